"""The doctor's checks: every module here registers its checks with
:func:`fap_py.doctor._registry.check` (found by name; docs/doctor.md lists them)."""
