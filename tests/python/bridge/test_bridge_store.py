"""The outbox and the seen-id set on disk: order, bound, persistence."""
from __future__ import annotations

import pytest

from fap_py.bridge.store import Store, now_iso
from fap_py.errors import PortError


def test_outbox_order_ack_and_reopen(tmp_path):
    path = str(tmp_path / "s.sqlite")
    with Store(path) as st:
        seqs = [st.put(f"t/{i}", b"p%d" % i, retain=i == 2) for i in range(5)]
        assert seqs == sorted(seqs) and st.pending == 5
        rows = st.after(0, 3)
        assert [r[1] for r in rows] == ["t/0", "t/1", "t/2"] and rows[2][3] is True
        st.delete([seqs[0], seqs[1]])
        assert st.pending == 3
    with Store(path) as st:          # what was not acknowledged survives a restart
        assert st.pending == 3
        assert [r[2] for r in st.after(0, 10)] == [b"p2", b"p3", b"p4"]
        assert st.next_seq() == seqs[-1] + 1          # numbers are never reused
        st.delete([s for s, *_ in st.after(0, 10)])
        assert st.next_seq() == seqs[-1] + 1


def test_outbox_bound_drops_oldest_and_counts(tmp_path):
    path = str(tmp_path / "s.sqlite")
    with Store(path, queue_max=10) as st:
        for i in range(25):
            st.put("t", b"%d" % i)
        assert st.pending == 10 and st.dropped == 15
        assert [r[2] for r in st.after(0, 100)] == [b"%d" % i for i in range(15, 25)]
        st.put_many([("t", b"x", False)] * 3)
        assert st.pending == 10 and st.dropped == 18
    with Store(path, queue_max=10) as st:
        assert st.dropped == 18


def test_seen_ids_persist_and_are_bounded(tmp_path):
    path = str(tmp_path / "s.sqlite")
    with Store(path, seen_max=10) as st:
        assert st.first_time("a") and not st.first_time("a")
        for i in range(30):
            assert st.first_time(f"id{i}")
    with Store(path, seen_max=10) as st:
        assert not st.first_time("id29")      # recent ids survive a restart
        assert st.first_time("a")             # the oldest were forgotten (bounded)


def test_unusable_state_dir(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(PortError):
        Store(str(tmp_path / "file" / "s.sqlite"))


def test_timestamp_format():
    assert now_iso(0.5) == "1970-01-01T00:00:00.500000Z"
