"""``vlaprobe doctor``: whether this machine will run ``vlaprobe run`` with given settings, in one command.

Each check prints one line (✓ ok, ! warning, ✗ failure, - skipped) with what it found, its fix and its time:
Python and the pinned packages (:mod:`~vlaprobe.doctor.system`), torch's build and device, LIBERO and each
suite's assets (:mod:`~vlaprobe.doctor.libero`), the model (:mod:`~vlaprobe.doctor.policy`), the free disk, the
renderer backends in subprocesses (:mod:`~vlaprobe.doctor.render`) and the tools of the tests.
:func:`~vlaprobe.doctor.command.doctor` runs them all.
"""
