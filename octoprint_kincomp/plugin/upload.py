"""Upload-time file compensation: the stream OctoPrint's preprocessor hook saves an upload
through, compensated line by line (OctoPrint glue around the core compensator)."""

from __future__ import annotations

from octoprint.filemanager.util import LineProcessorStream

from ..core.compensator import Options
from ..core.lines import UNIVERSAL, join_output, split_ending
from ..core.marker import ENCODING, ERRORS, MARKER_SCAN_LINES, marker_hash
from ..core.params import Params
from ..engines.files import marker_line
from ..engines.select import make_compensator


class CompensatingStream(LineProcessorStream):
    """Compensates an upload while OctoPrint saves it (one line at a time, O(1) memory).

    The first output line is KinComp's marker; a file that already carries a marker among
    its first ``MARKER_SCAN_LINES`` lines (e.g. after lines another preprocessor put first)
    is passed through unchanged (never compensated twice). Those first lines are read
    before anything is written, so the decision covers all of them.
    """

    def __init__(self, input_stream, params: Params, options: Options):
        super().__init__(input_stream)
        self.params = params
        self.comp = make_compensator(params, options)
        self.started = False
        self.passthrough = False

    def process_line(self, line: bytes) -> bytes:
        if not self.started:
            self.started = True
            head = [line]
            while len(head) < MARKER_SCAN_LINES:
                more = self.input_stream.readline()
                if not more:
                    break
                head.append(more)
            return self._head(b"".join(head))
        if self.passthrough:
            return line
        return self._lines(line.decode(ENCODING, ERRORS)).encode(ENCODING, ERRORS)

    def _head(self, data: bytes) -> bytes:
        text = data.decode(ENCODING, ERRORS)
        raws = UNIVERSAL.findall(text) or [text]
        bodies = [split_ending(raw)[0] for raw in raws[:MARKER_SCAN_LINES]]
        if any(marker_hash(b) is not None for b in bodies):
            self.passthrough = True
            return data
        first_ending = split_ending(raws[0])[1]
        return (marker_line(self.params) + (first_ending or "\n") + self._lines(text)).encode(
            ENCODING, ERRORS
        )

    def _lines(self, text: str) -> str:
        out = []
        for raw in UNIVERSAL.findall(text) or [text]:
            body, ending = split_ending(raw)
            res = self.comp.process(body)
            out.append(raw if res is body else join_output(res, ending))
        return "".join(out)
