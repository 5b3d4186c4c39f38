"""Attacks on the control link through the live proxy on loopback (issue 17, acceptance 3).

The generator's flight controller and mission computer talk MAVLink/UDP through the proxy
(lockstep, as in tests/test_proxy.py); the proxy forges a COMMAND_LONG or silences the link, and
the flight controller's commander reacts exactly as in simulation mode on the same seed.
"""

from __future__ import annotations

import socket

import numpy as np
import pytest
from conftest import truth

pytest.importorskip("pymavlink")

from scart_bench.dataset.schema import TRUTH_FIELDS  # noqa: E402
from scart_bench.generator.mavlink.codec import CODECS, KNOWN, Packer, split_frames  # noqa: E402
from scart_bench.generator.mavlink.link import MavlinkLink  # noqa: E402
from scart_bench.generator.mavlink.proxy import MavlinkProxy, ProxyError  # noqa: E402
from scart_bench.generator.scart.scenario import scenario_from_dict  # noqa: E402

SEED = 5
X, Y, Z = (TRUTH_FIELDS.index(k) for k in ("x", "y", "z"))
LOCAL = ("127.0.0.1", 0)


def _sc(sid: str, point: str, action: dict, seconds: float | None = None, start_s: float = 14.0):
    table = {"id": sid, "injection_point": point, "start": [{"condition": "time_window", "start_s": start_s}],
             "actions": [action]}
    if seconds is not None:
        table["end"] = [{"condition": "duration", "seconds": seconds}]
    return scenario_from_dict(table)


DISARM = _sc("disarm", "command", {"action": "inject_command", "command": "disarm"})
NO_FORCE = _sc("disarm-noforce", "command", {"action": "inject_command", "command": "disarm", "force": False})
LOSS = _sc("loss", "link", {"action": "link_loss"}, seconds=5.0)
REPLAY = _sc("replay", "link", {"action": "replay", "span_s": 2.0}, seconds=4.0)
FLOOD = _sc("flood", "link", {"action": "flood", "rate_hz": 200.0}, seconds=6.0)
CASES = (DISARM, NO_FORCE, LOSS, REPLAY, FLOOD)


@pytest.fixture(scope="module")
def reference():
    from scart_bench.generator.modes import simulation_mode

    batch, layer = simulation_mode([SEED] * len(CASES), [[c] for c in CASES])
    return batch, layer


def _loopback(scenario):
    from scart_bench.generator.engine.simulate import simulate

    with MavlinkLink() as link:
        proxy = MavlinkProxy(LOCAL, link.mission_computer_address, [scenario], seed=SEED).start()
        try:
            link.connect(proxy.listen_address)
            batch = simulate([SEED], layer=link)
        finally:
            proxy.stop()
    return batch, proxy


@pytest.mark.parametrize("case", range(len(CASES)), ids=["forged-disarm", "refused-disarm", "link-loss", "replay",
                                                         "flood"])
def test_control_link_attacks_through_the_proxy_act_as_in_simulation_mode(reference, case):
    """A forged command (accepted or refused), a link loss, a replay and a flood: same path, same end."""
    ref, _ = reference
    batch, proxy = _loopback(CASES[case])
    assert batch.status[0] == ref.status[case]
    (_, live), (_, sim) = truth(batch, 0), truth(ref, case)
    assert abs(len(live) - len(sim)) <= 1, "the flight ends at the same time"
    n = min(len(live), len(sim))
    off = np.abs(live[:n, [X, Y, Z]] - sim[:n, [X, Y, Z]]).max()
    assert off < 0.5, f"live and simulation-mode paths differ by {off:.2f} m"
    st = proxy.stats
    if case == 0:
        assert ref.status[0] == "crashed" and st.forged == 1
    elif case == 1:
        assert ref.status[1] == "landed" and st.forged == 1, "sent, and refused by the flight controller"
    elif case == 2:
        assert st.lost > 0 and st.forged == 0 and st.errors == 0
    elif case == 3:
        assert st.altered > 0 and st.dropped == 0 and st.errors == 0
    else:
        # 200 frames/s for 6 s in each direction of the link
        assert st.flooded == pytest.approx(2 * 200 * 6.0, rel=0.02) and st.dropped > 0 and st.errors == 0


def test_a_signed_stream_refuses_forged_frames_and_the_proxy_says_so():
    """With MAVLink 2 signing on the command stream the proxy has no key: it sends no forged frame
    (the autopilot would refuse it) and says so once."""
    from scart_bench.generator.mavlink import require_pymavlink

    mavlink = require_pymavlink()
    said = []
    mc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mc.bind(LOCAL)
    mc.settimeout(2.0)
    ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ap.bind(LOCAL)
    ap.settimeout(2.0)
    at_once = _sc("disarm-now", "command", {"action": "inject_command", "command": "disarm"}, start_s=0.0)
    proxy = MavlinkProxy(LOCAL, mc.getsockname(), [at_once], log=said.append).start()
    try:
        packer = Packer()
        ap.sendto(packer.pack(KNOWN[0](2, 12, 0, 0, 4, 3), 1, 1, 1), proxy.listen_address)
        _, back = mc.recvfrom(65535)
        signer = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
        signer.signing.secret_key = bytes(range(32))
        signer.signing.sign_outgoing = True
        signer.signing.timestamp = 1
        sp = CODECS["setpoint"]
        for signed in (True, False):
            dgram = (sp.new_message(np.array([1.0, 0.0, 0.0, 0.0, 1.0, 1.0]), 15_000_000).pack(signer) if signed
                     else packer.pack(sp.new_message(np.array([1.0, 0.0, 0.0, 0.0, 1.0, 1.0]), 15_020_000), 1, 191, 2))
            mc.sendto(dgram, back)
            data, _ = ap.recvfrom(65535)
            frames, _ = split_frames(data)
            ids = [f.msgid for f in frames]
            if signed:
                assert data == dgram and 76 not in ids, "the signed setpoint passes; nothing is forged"
                assert proxy.stats.refused_signed == 1 and any("signed" in s for s in said)
        # the attack is still on: an unsigned stream gets nothing forged either, the command was
        # sent once, at the attack's first setpoint (the one that was signed)
        assert proxy.stats.forged == 0
    finally:
        proxy.stop()
        ap.close()
        mc.close()


def test_mission_tamper_is_refused_by_the_proxy():
    tamper = _sc("tamper", "command", {"action": "mission_tamper"})
    with pytest.raises(ProxyError, match="mission_tamper"):
        MavlinkProxy(LOCAL, ("127.0.0.1", 9), [tamper])
