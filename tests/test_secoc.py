"""Authenticated frames (``[bus] authentication = "secoc"``): the layout in the DBC, signing and
verification, and masses-spoofing's attacks with and without authentication."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from cosim import scenario
from cosim.analysis.metrics import compute_metrics
from cosim.bus.codec import Codec
from cosim.bus.keys import SECRET_ENV, derive_key
from cosim.bus.secoc import BAD_MAC, REPLAYED, STALE, TRAILER, WINDOW, SecOC
from cosim.errors import CosimError, ScenarioError
from cosim.log.reader import LogReader
from cosim.log.recorder import SECURITY
from cosim.run import run
from cosim.run.node import NodeSpec, load_spec
from cosim.run.plan import RunPlan
from cosim.scenario.overrides import apply

SECRET = bytes(range(32))


def _loaded(**settings):
    return apply(scenario.load("masses-spoofing"), settings)


def _codec() -> Codec:
    return _loaded(**{"bus.authentication": "secoc"}).scenario.codec()


def _secoc(codec: Codec) -> SecOC:
    secoc = SecOC.from_codec(codec, {s.sender: derive_key(SECRET, s.sender) for s in codec.specs.values()})
    assert secoc is not None
    return secoc


def test_the_dbc_describes_the_trailer_after_the_authentic_pdu():
    plain = _loaded().scenario.codec()
    codec = _codec()
    assert not plain.secoc_trailers and "secoc_mac" not in plain.dbc
    sensor = codec.database.get_message_by_name("SENSOR_x1")
    assert codec.secoc_trailers[sensor.frame_id] == 12  # tick (4) + x1 (8), then FV (1) and MAC (3)
    assert sensor.length == 16 and plain.database.get_message_by_name("SENSOR_x1").length == 12
    estimate = codec.database.get_message_by_name("EST_kalman")
    assert codec.secoc_trailers[estimate.frame_id] == 36 and estimate.length == 48  # 40 bytes round up to 48
    assert set(codec.secoc_trailers) == {s.frame_id for s in codec.specs.values() if s.channels}  # data frames only
    # the DBC text carries the two signals; read back, the codec is the same (its signals without them)
    again = Codec._parse(codec.dbc)  # a parse of its own, not the codec from_dbc shares
    assert again is not codec and again.secoc_trailers == codec.secoc_trailers and again.dbc == codec.dbc
    assert again.specs == codec.specs == Codec.from_dbc(plain.dbc).specs
    assert "SG_ secoc_fv : 96|8@1+" in codec.dbc and "SG_ secoc_mac : 104|24@1+" in codec.dbc
    frame = codec.encode("SENSOR_x1", 7, [0.25])
    assert len(frame.data) == 16 and codec.decode(frame).values == {"x1": 0.25}


def test_a_signed_frame_passes_once_and_what_is_altered_or_old_does_not():
    codec = _codec()
    sender, receiver = _secoc(codec), _secoc(codec)
    frames = {}
    for k in range(300):
        frame = codec.encode("SENSOR_x1", k, [k / 1000])
        sender.sign(frame, k)
        frames[k] = frame
        assert frame.data[12] == k % 256
        assert receiver.verify(frame, k) is None
    assert receiver.verify(frames[299], 299).reason == REPLAYED  # the same frame again
    assert receiver.verify(frames[299 - 100], 299).reason == REPLAYED  # recorded 100 ticks ago
    assert receiver.verify(frames[299 - 256], 299).reason == BAD_MAC  # its FV rebuilt as 299: the MAC fails
    for byte in (0, 5, 12, 13, 15):  # the tick, a value, the FV, the MAC
        forged = codec.encode("SENSOR_x1", 300, [0.3])
        forged.data[:] = frames[299].data
        forged.data[byte] ^= 0x01
        assert receiver.verify(forged, 300).reason == BAD_MAC
    # a genuine frame that comes later than the window
    late = codec.encode("SENSOR_x1", 300, [0.3])
    sender.sign(late, 300)
    assert receiver.verify(late, 300 + WINDOW + 1).reason == STALE
    assert receiver.verify(late, 300 + WINDOW) is None
    # another sender's key cannot sign the plant's frames
    other = SecOC(
        {"plant": derive_key(SECRET, "kalman")}, codec.secoc_trailers, {i: "plant" for i in codec.secoc_trailers}
    )
    forged = codec.encode("SENSOR_x1", 400, [0.3])
    other.sign(forged, 400)
    assert receiver.verify(forged, 400).reason == BAD_MAC
    assert TRAILER == 4


def test_secoc_needs_can_fd_and_nodes_it_starts(tmp_path):
    with pytest.raises(ScenarioError, match=r'bus.authentication: "secoc" needs CAN FD.*fd = true') as error:
        _loaded(**{"bus.authentication": "secoc", "bus.fd": False})
    assert "\n" not in str(error.value)
    with pytest.raises(ScenarioError, match=r"bus.authentication: .*estimators.kalman is started by hand"):
        _loaded(**{"bus.authentication": "secoc", "estimators[1].external": True})
    with pytest.raises(ScenarioError, match="bus.authentication"):
        _loaded(**{"bus.authentication": "hmac"})


def test_keys_reach_the_nodes_in_a_spec_that_is_deleted_once_read(tmp_path):
    plan = RunPlan.build(_loaded(**{"bus.authentication": "secoc"}))
    assert plan.secret is not None and len(plan.secret) == 32
    from cosim.bus.transport import BusConfig

    spec = plan.node_spec("kalman", BusConfig("virtual", "x"))
    assert set(spec.keys) == {"kalman", "plant", "controller"}
    assert spec.keys["plant"] == derive_key(plan.secret, "plant").hex()
    assert plan.secret.hex() not in spec.to_json()
    path = tmp_path / "kalman.json"
    path.write_text(spec.to_json())
    assert load_spec(path).keys == spec.keys and not path.exists()
    unsecured = RunPlan.build(_loaded()).node_spec("kalman", BusConfig("virtual", "x"))
    assert unsecured.keys == {} and "keys" not in json.loads(unsecured.to_json())
    assert NodeSpec.from_json(unsecured.to_json()).keys == {}


def _estimates(path) -> dict[str, np.ndarray]:
    """Each estimator's estimate frames' values, in tick order."""
    out: dict[str, list[list[float]]] = {}
    with LogReader(path) as reader:
        for topic, _, msg in reader.messages(["/can/EST_uniform", "/can/EST_kalman"]):
            out.setdefault(topic, []).append([msg["tick"], msg["xhat_x1"], msg["xhat_x2"]])
    return {topic: np.array(rows) for topic, rows in out.items()}


def _errors(path) -> dict[str, float]:
    """Each estimator's worst |x̂ − x| over both positions during the attacks (5-17 s)."""
    with LogReader(path) as reader:
        truth = {m["tick"]: (m["x1"], m["x2"]) for _, _, m in reader.messages(["/truth/state"])}
    worst = {}
    for topic, rows in _estimates(path).items():
        during = rows[(rows[:, 0] >= 500) & (rows[:, 0] < 1700)]
        x = np.array([truth[int(k)] for k in during[:, 0]])
        worst[topic] = float(np.abs(during[:, 1:] - x).max())
    return worst


@pytest.mark.slow
@pytest.mark.parametrize("timing", ["ideal", "arbitrated"])
def test_masses_spoofing_is_contested_without_secoc_and_rejected_with_it(tmp_path, timing):
    settings = {"bus.timing": timing} if timing == "ideal" else {"bus.timing": timing, "duration": 14.0}
    runs, contested = {}, {}
    for name, more in {
        "clean": {"bus.authentication": "secoc", "faults": []},
        "open": {"bus.authentication": "none"},
        "secoc": {"bus.authentication": "secoc"},
    }.items():
        out = tmp_path / f"{name}.mcap"
        result = run(_loaded(**settings, **more), out, 0, interface="virtual")
        assert result.status == "completed", result.error
        runs[name] = out
        contested[name] = result.contested_ticks
    clean, open_, secured = (_estimates(runs[n]) for n in ("clean", "open", "secoc"))
    # with SecOC the estimate frames carry exactly the attack-free run's values
    for topic in clean:
        assert np.array_equal(secured[topic], clean[topic]), topic
    # without it every receiver gets two copies of each attacked message per tick and trusts neither:
    # the readings are missing rather than forged, and the estimates stay near the attack-free run's
    errors = {name: _errors(path) for name, path in runs.items()}
    for topic in clean:
        assert errors["secoc"][topic] == errors["clean"][topic] < 0.002
        assert errors["open"][topic] < 0.005, errors
    # every intruder frame is rejected, and nothing else
    injected = Counter()
    with LogReader(runs["secoc"]) as reader:
        for _, _, m in reader.messages(["/truth/bus_faults"]):
            injected[m["message"]] += m["event"] == "injected"
        rejected = Counter((m["message"], m["reason"]) for _, _, m in reader.messages([SECURITY]))
    assert rejected == {("SENSOR_x1", BAD_MAC): injected["SENSOR_x1"], ("SENSOR_x2", REPLAYED): injected["SENSOR_x2"]}
    assert injected["SENSOR_x1"] == 500 and injected["SENSOR_x2"] == (500 if timing == "ideal" else 200)
    # unauthenticated, every tick an intruder sent in is contested; authenticated, none is
    assert contested == {"clean": 0, "open": injected["SENSOR_x1"] + injected["SENSOR_x2"], "secoc": 0}
    metrics = compute_metrics(runs["secoc"])
    assert metrics["bus"]["secoc_rejected"] == {
        "0x100": {"bad_mac": injected["SENSOR_x1"]},
        "0x101": {"replayed": injected["SENSOR_x2"]},
    }
    assert "secoc_rejected" not in compute_metrics(runs["clean"])["bus"]
    print(
        timing,
        {name: {t.removeprefix("/can/EST_"): round(e, 4) for t, e in err.items()} for name, err in errors.items()},
    )


@pytest.mark.slow
def test_node_processes_verify_what_they_hear(tmp_path):
    """The same attacks on udp_multicast, the estimators in processes of their own holding their
    keys: their estimates are the attack-free run's, and the runner saw every intruder's frame."""
    attack_free = tmp_path / "clean.mcap"
    run(_loaded(**{"bus.authentication": "secoc", "faults": []}), attack_free, 0, interface="virtual")
    out = tmp_path / "udp.mcap"
    result = run(_loaded(**{"bus.authentication": "secoc"}), out, 0, interface="udp_multicast")
    assert result.status == "completed", result.error
    clean, secured = _estimates(attack_free), _estimates(out)
    for topic in clean:
        assert np.array_equal(secured[topic], clean[topic]), topic
    assert compute_metrics(out)["bus"]["secoc_rejected"] == {"0x100": {"bad_mac": 500}, "0x101": {"replayed": 500}}


def test_a_node_drops_and_counts_what_fails():
    """A node's client: the intruder's frame after the genuine one is dropped, the tick is the genuine one's."""
    import can

    from cosim.bus.client import Client

    codec = _codec()
    secoc = _secoc(codec)
    bus = can.Bus(interface="virtual", channel="secoc-node", receive_own_messages=False)
    client = Client("kalman", codec, bus, secoc=_secoc(codec), upstream={})
    genuine = [codec.encode(f"SENSOR_{name}", 3, [0.1]) for name in ("x1", "x2", "x1_minus_x2")]
    genuine.append(codec.encode("COMMAND_force", 3, [0.2]))
    for frame in genuine:
        secoc.sign(frame, 3)
    spoofed = codec.encode("SENSOR_x1", 3, [0.5])  # no key: its trailer stays zeros
    ticks = client.feed(codec.sync(3, 4)) + [t for f in genuine[:1] + [spoofed] + genuine[1:] for t in client.feed(f)]
    assert [t.tick for t in ticks] == [3] and ticks[0].sensors["x1"] == 0.1
    assert client.rejections == {(0x100, BAD_MAC): 1}
    assert client.feed(genuine[0]) == [] and client.rejections[(0x100, REPLAYED)] == 1
    bus.shutdown()


def test_a_replay_of_a_secured_run_leaves_out_what_its_receivers_dropped(tmp_path):
    from cosim.run.replay import Replay

    out = tmp_path / "secured.mcap"
    assert run(_loaded(**{"bus.authentication": "secoc", "duration": 7.0}), out, 0, interface="virtual").status == (
        "completed"
    )
    again = tmp_path / "again.mcap"
    result = Replay(out, again, "kalman", interface="virtual").execute()
    assert result.status == "completed", result.error
    assert np.array_equal(_estimates(again)["/can/EST_kalman"], _estimates(out)["/can/EST_kalman"])


def test_a_fixed_run_secret_repeats_a_secured_run_bit_for_bit(tmp_path, monkeypatch):
    """Without COSIM_RUN_SECRET two runs of a seed differ in their trailers only; with it, in nothing."""
    from tests.frame_digests import log_digest

    loaded = _loaded(**{"bus.authentication": "secoc", "duration": 0.5})
    digests = []
    for i, secret in enumerate(["", "", "ab" * 32, "ab" * 32]):
        monkeypatch.setenv(SECRET_ENV, secret)
        out = tmp_path / f"run{i}.mcap"
        assert run(loaded, out, 0, interface="virtual").status == "completed"
        digests.append(log_digest(out))
    assert digests[0] != digests[1] and digests[2] == digests[3]
    assert [_estimates(tmp_path / f"run{i}.mcap")["/can/EST_kalman"].tolist() for i in (0, 2)] == [
        _estimates(tmp_path / f"run{i}.mcap")["/can/EST_kalman"].tolist() for i in (1, 3)
    ]
    monkeypatch.setenv(SECRET_ENV, "abc")
    with pytest.raises(CosimError, match="COSIM_RUN_SECRET must be 64 hex digits"):
        RunPlan.build(loaded)
