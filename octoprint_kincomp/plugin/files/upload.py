"""Upload-time file compensation: the stream OctoPrint's preprocessor hook saves an upload
through, compensated by the file loop (``engines/file_loop.py`` FileEngine) as it passes."""

from __future__ import annotations

from octoprint.filemanager.util import LineProcessorStream

from ...core.compensator import Options
from ...core.marker import ENCODING, ERRORS, MARKER_SCAN_LINES, ballbar_record
from ...core.params import Params
from ...engines.file_loop import FileEngine, head_marker, marker_line
from ...engines.select import make_compensator


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
        self.engine = FileEngine(self.comp)
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
        return self.engine.chunk(line)

    def _head(self, data: bytes) -> bytes:
        if head_marker(data.decode(ENCODING, ERRORS)) is not None:
            self.passthrough = True
            return data
        opts = self.comp.options
        record = ballbar_record(data.decode(ENCODING, ERRORS), opts.decimals, opts.deadband_mm)
        header = marker_line(self.params) + ("\n" + record if record else "")
        return self.engine.header(header, data) + self.engine.chunk(data)
