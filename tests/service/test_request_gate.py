"""KinComp's requests rationed while a print runs (``service/request_gate.py``, issue 37
row 6): nothing rationed without a print; a burst passes at once, then each user gets its
rate and all users together theirs; a request over its ration waits for its turn (sleeping)
while few wait and the turn is near, else it is refused with the seconds to wait."""

import threading

from octoprint_kincomp.service.request_gate import RequestGate


class Clock:
    def __init__(self):
        self.now = 100.0
        self.slept = []

    def __call__(self):
        return self.now

    def sleep(self, s):
        self.slept.append(round(s, 6))


def gate(active=True, **kw):
    clock = Clock()
    state = {"printing": active}
    g = RequestGate(lambda: state["printing"], clock=clock, sleep=clock.sleep, **kw)
    return g, clock, state


def test_nothing_is_rationed_without_a_print():
    g, clock, _ = gate(active=False, per_user_burst=1, burst=1)
    assert all(g.admit("admin") is None for _ in range(1000))
    assert clock.slept == [] and g.refused == 0


def test_a_burst_passes_then_the_users_rate_by_waiting_for_the_turn():
    g, clock, _ = gate(per_user_rate=2.0, per_user_burst=3, rate=100.0, burst=100)
    assert [g.admit("a") for _ in range(3)] == [None] * 3 and clock.slept == []
    assert g.admit("a") is None  # the 4th waits half a second (2 a second)
    assert clock.slept == [0.5]
    clock.now += 0.5  # (its turn came; the next is reserved half a second later)
    assert g.admit("a") is None and clock.slept == [0.5, 0.5]
    # another user has a bucket of its own
    assert g.admit("b") is None and clock.slept == [0.5, 0.5]
    # after a pause the bucket is full again (never more than the burst)
    clock.now += 60.0
    assert [g.admit("a") for _ in range(3)] == [None] * 3 and clock.slept == [0.5, 0.5]


def test_all_users_together_have_a_ration_too():
    g, clock, _ = gate(per_user_rate=100.0, per_user_burst=100, rate=4.0, burst=2)
    assert g.admit("a") is None and g.admit("b") is None and clock.slept == []
    assert g.admit("c") is None and clock.slept == [0.25]  # the common bucket's turn


def test_a_turn_too_far_off_is_refused_with_the_seconds_to_wait():
    g, clock, _ = gate(per_user_rate=0.2, per_user_burst=1, rate=100.0, burst=100, max_wait_s=2)
    assert g.admit("a") is None
    assert g.admit("a") == 5.0  # its turn in 5 s: not waited for, refused
    assert g.refused == 1 and clock.slept == []
    clock.now += 5.0
    assert g.admit("a") is None  # the refused one took no turn


def test_at_most_max_waiting_wait_the_others_are_refused():
    clock = Clock()
    release = threading.Event()
    waiting = threading.Semaphore(0)

    def sleep(s):
        waiting.release()
        assert release.wait(10)

    g = RequestGate(
        lambda: True,
        per_user_rate=10.0,
        per_user_burst=1,
        rate=100.0,
        burst=100,
        max_waiting=2,
        clock=clock,
        sleep=sleep,
    )
    assert g.admit("a") is None
    results = []
    threads = [threading.Thread(target=lambda: results.append(g.admit("a"))) for _ in range(2)]
    for t in threads:
        t.start()
    for _ in threads:
        assert waiting.acquire(timeout=10)  # both wait for their turns
    assert g.waiting == 2
    assert g.admit("a") == 1.0  # a third is refused (Retry-After 1 s)
    release.set()
    for t in threads:
        t.join(10)
    assert results == [None, None] and g.waiting == 0


def test_a_print_ending_ends_the_ration():
    g, clock, state = gate(per_user_rate=0.1, per_user_burst=1, max_wait_s=1)
    assert g.admit("a") is None and g.admit("a") == 10.0
    state["printing"] = False
    assert g.admit("a") is None
