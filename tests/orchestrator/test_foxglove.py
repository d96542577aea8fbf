"""Foxglove 3D view: quaternions against scipy's rotations, and /tf follows the logged pose."""
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation

from immersim.orchestrator.errors import ScenarioError
from immersim.orchestrator.execution import run_scenario
from immersim.orchestrator.foxglove import euler_quaternion
from immersim.orchestrator.mcapio import read_series

from .helpers import MASS_BODY, oscillator_scenario

angles = st.floats(-3.0, 3.0)


@settings(max_examples=200, deadline=None)
@given(angles, angles, angles)
def test_quaternions_match_scipy(e1, e2, e3):
    q = euler_quaternion(e1, e2, e3, "xyz")  # A = A_x A_y A_z: intrinsic X, Y, Z
    ref = Rotation.from_euler("XYZ", [e1, e2, e3]).as_quat()
    assert min(np.abs(np.subtract(q, ref)).max(), np.abs(np.add(q, ref)).max()) < 1e-12
    q = euler_quaternion(e1, e2, e3, "zyx")  # R = R_z(yaw) R_y(pitch) R_x(roll)
    ref = Rotation.from_euler("ZYX", [e3, e2, e1]).as_quat()
    assert min(np.abs(np.subtract(q, ref)).max(), np.abs(np.add(q, ref)).max()) < 1e-12


def test_tf_follows_the_signals(tmp_path, test_fmus):
    extra = MASS_BODY
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=0.66, extra=extra)
    out = tmp_path / "fg.mcap"
    run_scenario(scn, out)
    series = read_series(out, ["m1.x", "m2.x"])
    with open(out, "rb") as fh:
        msgs = [(c.topic, json.loads(m.data)) for _, c, m in make_reader(fh).iter_messages(topics=["/tf", "/scene"])]
    tf = [m["transforms"][0] for t, m in msgs if t == "/tf"]
    scene = [m for t, m in msgs if t == "/scene"]
    assert len(tf) == 21 and len(scene) == 1   # the fixed shapes: once per simulated second
    np.testing.assert_allclose([x["translation"]["x"] for x in tf], series["m1.x"][1], atol=0)
    yaw = series["m2.x"][1]
    np.testing.assert_allclose([x["rotation"]["z"] for x in tf], np.sin(yaw / 2), atol=1e-15)
    assert scene[0]["entities"][0]["cubes"][0]["size"] == {"x": 0.2, "y": 0.2, "z": 0.2}
    assert tf[0]["child_frame_id"] == "mass1" and tf[0]["parent_frame_id"] == "world"
    # "*" selects the units' signals, not the 3D view's arrays (they are not numbers)
    every = read_series(out, ["*"])
    assert every and all(k.split(".")[0] in ("m1", "m2") for k in every)


def test_bad_body_reference(tmp_path, test_fmus):
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], extra='''
[[foxglove.bodies]]
name = "b"
position = ["m1.nope", 0.0, 0.0]
''')
    with pytest.raises(ScenarioError, match=r"foxglove body 'b': unit m1 \(oscillator.fmu\) has no variable 'nope'"):
        run_scenario(scn, tmp_path / "x.mcap")


def test_scene_once_per_second_and_fixed_bodies(tmp_path, test_fmus):
    """/scene at t = 0 and then once per simulated second; a body given only numbers has the
    same transform in every /tf message (computed once), stamped with the step's time."""
    extra = """
[[foxglove.bodies]]
name = "post"
position = [1.0, 2.0, 0.0]
euler = [0.0, 0.0, 1.5707963267948966]
order = "zyx"
offset = [0.0, 0.0, 0.5]
"""
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.1, stop=2.5, extra=extra)
    out = tmp_path / "fg.mcap"
    run_scenario(scn, out)
    with open(out, "rb") as fh:
        msgs = [(c.topic, m.log_time, json.loads(m.data))
                for _, c, m in make_reader(fh).iter_messages(topics=["/tf", "/scene"])]
    assert [t for topic, t, _ in msgs if topic == "/scene"] == [0, 1_000_000_000, 2_000_000_000]
    tfs = [(t, m["transforms"][0]) for topic, t, m in msgs if topic == "/tf"]
    assert len(tfs) == 26
    for t, tr in tfs:
        assert tr["translation"] == {"x": 1.0, "y": 2.0, "z": 0.5}
        assert tr["rotation"]["z"] == pytest.approx(np.sqrt(0.5), abs=1e-15) and tr["rotation"]["x"] == 0.0
        assert tr["timestamp"]["sec"] * 10**9 + tr["timestamp"]["nsec"] == t


def test_ros1_tf_equals_the_json_tf_and_decodes_with_the_reference_decoder(tmp_path, test_fmus):
    """``[log] encoding = "ros1"``: /tf as ROS 1 tf2_msgs/TFMessage holds the transforms of the
    JSON log bit for bit (our decoder), mcap_ros1's DecoderFactory reads the same numbers, and
    the log's signals stay readable ("*" selects no /tf array)."""
    from mcap_ros1.decoder import DecoderFactory

    from immersim.orchestrator.foxglove import read_transforms

    body = MASS_BODY + '''
[[foxglove.bodies]]
name = "plate"
position = ["m2.x", "m1.x", 1.0]
euler = ["m1.x", "m2.x", 0.3]
order = "xyz"
offset = [0.1, 0.2, 0.3]

[[foxglove.bodies]]
name = "post"
position = [1.0, 2.0, 0.0]
euler = [0.0, 0.5, 0.0]
'''
    logs = {}
    for enc in ("json", "ros1"):
        scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=0.66, name=f"{enc}.toml",
                                  extra=f'[log]\nencoding = "{enc}"\n' + body)
        logs[enc] = tmp_path / f"{enc}.mcap"
        run_scenario(scn, logs[enc])
    a, b = read_transforms(logs["json"]), read_transforms(logs["ros1"])
    assert len(a) == 21 and a == b
    with open(logs["ros1"], "rb") as fh:
        decoded = [(m.log_time, d) for _, c, m, d in make_reader(fh, decoder_factories=[DecoderFactory()])
                   .iter_decoded_messages(topics=["/tf"])]
    assert [t for t, _ in decoded] == [t for t, _ in b]
    for (t, ours), (_, ref) in zip(b, decoded):
        for x, y in zip(ours, ref.transforms):
            assert (y.header.frame_id, y.child_frame_id) == (x["parent_frame_id"], x["child_frame_id"])
            assert y.header.stamp.secs * 10**9 + y.header.stamp.nsecs == t
            assert [y.transform.translation.x, y.transform.translation.y, y.transform.translation.z] == \
                list(x["translation"].values())
            assert [y.transform.rotation.x, y.transform.rotation.y, y.transform.rotation.z,
                    y.transform.rotation.w] == list(x["rotation"].values())
    assert read_series(logs["ros1"], ["*"]).keys() == read_series(logs["json"], ["*"]).keys()
