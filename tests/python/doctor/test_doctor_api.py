"""The doctor's public Python API (fap_py.doctor): small, every argument checked,
a bad one refused with the package's own errors; the machinery is private."""
from __future__ import annotations

import json
import tarfile

import pytest
from doctor_helpers import DIALOUT

from fap_py import doctor
from fap_py.errors import FapError, FileError, InvalidTypeError, InvalidValueError

OBJ = object()


def test_public_api_is_small_and_the_rest_private():
    assert sorted(doctor.__all__) == ["EXIT_BY_SEVERITY", "Finding", "LISTEN_MAX_S", "SEVERITIES",
                                      "check_ids", "exit_code", "listen", "run", "worst",
                                      "write_bundle"]
    import pkgutil
    subs = [m.name for m in pkgutil.iter_modules(doctor.__path__)]
    assert subs and all(n.startswith("_") for n in subs), subs


def test_run_on_a_tree(tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00", latency=1)
    tree.write_groups()
    fs = doctor.run(root=str(tree.root), port="ttyUSB0", user="pi")
    assert fs and all(isinstance(f, doctor.Finding) for f in fs)
    sev = [doctor.SEVERITIES.index(f.severity) for f in fs]
    assert sev == sorted(sev, reverse=True)          # worst first
    assert doctor.worst(fs) == fs[0].severity
    assert doctor.exit_code(fs) == doctor.EXIT_BY_SEVERITY[fs[0].severity]
    only = doctor.run(root=str(tree.root), port="ttyUSB0", only=["perm.group"])
    assert {f.id for f in only} <= {"perm.group"}
    assert doctor.worst([]) == "ok" and doctor.exit_code(iter([])) == 0
    assert "perm.group" in doctor.check_ids() and DIALOUT


@pytest.mark.parametrize("kw", [
    {"root": 5}, {"root": None}, {"root": ""}, {"root": "a\0b"}, {"root": "/nonexistent/x"},
    {"port": 5}, {"port": ""}, {"user": 5}, {"user": ""}, {"user": "a\0"},
    {"kernel_log": 1.5}, {"baud": True}, {"baud": "9600"}, {"baud": 1234567},
    {"only": OBJ}, {"only": "perm.group"}, {"only": [5]}, {"only": ["no.such.check"]},
])
def test_run_refuses_bad_arguments(kw):
    with pytest.raises((InvalidTypeError, InvalidValueError)):
        doctor.run(**kw)


@pytest.mark.parametrize("bad", [OBJ, 5, "abc", b"x", [OBJ], [None]])
def test_worst_and_exit_code_refuse_what_is_not_findings(bad):
    for fn in (doctor.worst, doctor.exit_code):
        with pytest.raises(InvalidTypeError):
            fn(bad)


@pytest.mark.parametrize("kw", [
    {"id": 5}, {"id": ""}, {"severity": "fatal"}, {"severity": 3}, {"cause": None},
    {"evidence": "one line"}, {"evidence": [5]}, {"evidence": OBJ}, {"fix": None},
    {"port": 5}, {"detail": [1]},
])
def test_finding_checks_its_fields(kw):
    args = dict({"id": "x.y", "severity": "info", "cause": "c"}, **kw)
    with pytest.raises((InvalidTypeError, InvalidValueError)):
        doctor.Finding(**args)


def test_finding_evidence_tuple_is_a_list():
    f = doctor.Finding("x.y", "ok", "c", ("a", "b"))
    assert f.evidence == ["a", "b"] and f.as_event()["evidence"] == ["a", "b"]


@pytest.mark.parametrize("port,seconds", [
    (5, 1.0), ("", 1.0), ("a\0b", 1.0), (None, 1.0), ("/dev/null", 0), ("/dev/null", -1),
    ("/dev/null", float("nan")), ("/dev/null", float("inf")), ("/dev/null", True),
    ("/dev/null", "1"), ("/dev/null", doctor.LISTEN_MAX_S + 1), ("/dev/null", None),
])
def test_listen_refuses_bad_arguments(port, seconds):
    with pytest.raises((InvalidTypeError, InvalidValueError)):
        doctor.listen(port, seconds)


def test_listen_on_a_missing_port_is_an_error_finding(tmp_path):
    f = doctor.listen(str(tmp_path / "ttyNONE"), 0.05)
    assert f.id == "listen.bus" and f.severity == "error"


def test_write_bundle(tree, tmp_path):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00", latency=1)
    tree.write_groups()
    out = tmp_path / "b.tar.gz"
    n = doctor.write_bundle(str(out), root=str(tree.root), port="ttyUSB0", user="pi")
    assert n > 0
    with tarfile.open(out) as tar:
        report = tar.extractfile("fap-doctor/report.json").read().decode()
    assert all(json.loads(line)["event"] == "finding" for line in report.splitlines())
    with pytest.raises(FileError):
        doctor.write_bundle(str(tmp_path), root=str(tree.root))
    with pytest.raises(FileError):
        doctor.write_bundle(str(tmp_path / "no" / "dir.tar.gz"), root=str(tree.root))
    for kw in ({"path": 5}, {"path": ""}, {"path": str(out), "root": 5},
               {"path": str(out), "baud": 1.5}):
        with pytest.raises(FapError):
            doctor.write_bundle(**kw)
