import numpy as np
import pytest

from octoprint_kincomp.core.kinematics import KinematicModel
from octoprint_kincomp.core.params import Params


def model(**kw):
    return KinematicModel(Params.from_dict(kw))


def test_identity():
    m = model()
    assert m.is_identity and m.is_affine
    assert m.forward((1.5, -2.0, 3.0)) == (1.5, -2.0, 3.0)


@pytest.mark.parametrize(
    "pair, expect",
    [
        ("xy", lambda x, y, z, f: (x + f * y, y, z)),
        ("xz", lambda x, y, z, f: (x + f * z, y, z)),
        ("yz", lambda x, y, z, f: (x, y + f * z, z)),
    ],
)
def test_squareness_sign_contract(pair, expect):
    m = model(squareness_um_per_m={pair: 250.0})
    p = (12.0, 34.0, 56.0)
    assert m.forward(p) == pytest.approx(expect(*p, 250e-6), abs=1e-12)


@pytest.mark.parametrize("axis", "xyz")
def test_scale_sign_contract(axis):
    m = model(scale_ppm={axis: 300.0})
    p = np.array([100.0, 200.0, 50.0])
    want = p.copy()
    want["xyz".index(axis)] *= 1 + 300e-6
    assert m.forward(p) == pytest.approx(tuple(want), abs=1e-12)


def test_xy_squareness_equals_klipper_formula():
    """Klipper calc_skew: x' = x - y*f for the XY factor f (= xy * 1e-6)."""
    for xy in (-3638.6, -120.0, 55.5, 2000.0):
        m = model(squareness_um_per_m={"xy": xy})
        f = xy * 1e-6
        for x, y, z in ((0, 0, 0), (100, 200, 10), (-30, 255.5, 80)):
            q = m.inverse((x, y, z))
            assert q[0] == pytest.approx(x - y * f, abs=1e-12)
            assert q[1] == pytest.approx(y, abs=1e-12)
            assert q[2] == pytest.approx(z, abs=1e-12)


def test_klipper_full_three_plane_formula():
    """x' = x - y*xy - z*(xz - xy*yz), y' = y - z*yz (Klipper/Marlin skew())."""
    xy, xz, yz = 310e-6, -150e-6, 95e-6
    m = model(squareness_um_per_m={"xy": xy * 1e6, "xz": xz * 1e6, "yz": yz * 1e6})
    x, y, z = 123.0, 45.0, 67.0
    q = m.inverse((x, y, z))
    assert q[0] == pytest.approx(x - y * xy - z * (xz - xy * yz), abs=1e-12)
    assert q[1] == pytest.approx(y - z * yz, abs=1e-12)


def test_scale_only_inverse():
    for s in (-451.7, 287.0, 5000.0):
        m = model(scale_ppm={"x": s, "y": s / 2, "z": -s})
        q = m.inverse((100.0, 50.0, 20.0))
        assert q[0] == pytest.approx(100.0 / (1 + s * 1e-6), rel=1e-14)
        assert q[1] == pytest.approx(50.0 / (1 + s / 2 * 1e-6), rel=1e-14)
        assert q[2] == pytest.approx(20.0 / (1 - s * 1e-6), rel=1e-14)


def random_params(rng, kinematics, full):
    d = {
        "kinematics": kinematics,
        "squareness_um_per_m": {k: float(rng.uniform(-4000, 4000)) for k in ("xy", "xz", "yz")},
        "scale_ppm": {k: float(rng.uniform(-800, 800)) for k in "xyz"},
    }
    if full:
        errs = {}
        for a in "xyz":
            errs[a] = {
                "tx_um": [
                    float(rng.uniform(-20, 20)),
                    float(rng.uniform(-0.05, 0.05)),
                    float(rng.uniform(-2e-4, 2e-4)),
                ],
                "ty_um": [0.0, float(rng.uniform(-0.05, 0.05)), float(rng.uniform(-2e-4, 2e-4))],
                "tz_um": float(rng.uniform(-10, 10)),
                "rx_urad": [float(rng.uniform(-50, 50)), float(rng.uniform(-0.3, 0.3))],
                "ry_urad": [float(rng.uniform(-50, 50)), float(rng.uniform(-0.3, 0.3))],
                "rz_urad": [float(rng.uniform(-50, 50)), float(rng.uniform(-0.3, 0.3))],
            }
        d["axis_errors"] = errs
        d["nozzle_offset_mm"] = {a: float(rng.uniform(-40, 40)) for a in "xyz"}
    return Params.from_dict(d)


@pytest.mark.parametrize("kinematics", ["parallel", "bedslinger", "corexy"])
@pytest.mark.parametrize("full", [False, True])
def test_inverse_round_trip_random(kinematics, full):
    rng = np.random.default_rng(7 + full)
    for _ in range(15):
        m = KinematicModel(random_params(rng, kinematics, full))
        assert m.is_affine == (not full)
        pts = rng.uniform(-50, 350, size=(40, 3))
        for d in pts:
            q = m.inverse(d)
            assert np.max(np.abs(np.array(m.forward(q)) - d)) < 1e-9
        Q = m.inverse_many(pts)
        assert np.max(np.abs(m.forward_many(Q) - pts)) < 1e-9


def test_serial_chain_abbe_effect():
    """A bed-slinger's bed pitch (Y axis rotating about X) moves the nozzle in Y by -rx*z."""
    p = Params.from_dict({"kinematics": "bedslinger", "axis_errors": {"y": {"rx_urad": 100.0}}})
    m = KinematicModel(p)
    z = 50.0
    a = m.forward((10.0, 20.0, z))
    # small rotation rx about X of the Y carriage acts on everything it carries (Z, X, nozzle):
    # d = rx x (x, 0, z) -> dy = -rx*z, dz = 0 (x has no y/z component)... plus y-independent
    assert a[1] - 20.0 == pytest.approx(-100e-6 * z, abs=1e-12)
    assert a[0] == pytest.approx(10.0, abs=1e-12)
    par = KinematicModel(Params.from_dict({"axis_errors": {"y": {"rx_urad": 100.0}}}))
    # parallel kinematics: rotation only acts on the nozzle offset (zero here)
    assert par.forward((10.0, 20.0, z)) == pytest.approx((10.0, 20.0, z), abs=1e-12)


def test_nozzle_offset_abbe_parallel():
    p = Params.from_dict(
        {"axis_errors": {"x": {"rz_urad": 200.0}}, "nozzle_offset_mm": {"y": 30.0}}
    )
    m = KinematicModel(p)
    a = m.forward((0.0, 0.0, 0.0))
    # rz x (0, 30, 0) = (-rz*30, 0, 0)
    assert a[0] == pytest.approx(-200e-6 * 30.0, abs=1e-12)


def test_scale_and_squareness_compose_with_alignment_last():
    m = model(squareness_um_per_m={"xy": 1000.0}, scale_ppm={"y": 500.0})
    x, y, z = 10.0, 100.0, 0.0
    ax, ay, _ = m.forward((x, y, z))
    assert ay == pytest.approx(y * (1 + 500e-6))
    assert ax == pytest.approx(x + 1000e-6 * y * (1 + 500e-6))


def test_coupling_structure():
    m = model(squareness_um_per_m={"xy": 100.0})
    assert m.coupling[0][1] and not m.coupling[1][0] and not m.coupling[0][2]
