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
