"""The toy protocol itself works on a real virtual bus (so the tool tests below it are fair)."""

from toyproto import binding

from fap_py.vbus import VirtualBus


def test_codec_round_trip_and_rejects():
    d = binding.Decoder()
    frame = binding.encode(3, b"abc")
    assert d.feed(b"\x00" + frame[:2]) == []
    assert d.feed(frame[2:]) == [(3, b"abc")]
    assert d.feed(binding.encode(3, b"cba", reply=True)) == [(3 | binding.REPLY, b"cba")]
    bad = bytearray(frame)
    bad[-1] ^= 1
    assert d.feed(bytes(bad)) == []
    assert d.rejected >= 2


def test_master_and_slave_on_a_virtual_bus(toy_protocol):
    assert toy_protocol.node_max == binding.NODE_MAX
    with VirtualBus(ports=2) as bus:
        with binding.Slave(bus.paths[1], node=2).start() as slave, binding.Master(bus.paths[0]) as master:
            assert master.request(2, b"hello") == b"olleh"
            assert master.stats.frames_rx == 1
        assert slave.stats.frames_tx == 1


def test_a_child_process_sees_the_toy_through_the_environment(toy_env):
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-c", "from fap_py import _protocols as P; print(P.names())"],
                         env=toy_env, capture_output=True, text=True, timeout=60, check=True).stdout
    assert "'toy'" in out
