"""A process's memory as Linux reports it in ``/proc/<pid>``: the figures the benchmarks print.

``status`` gives ``VmRSS`` (resident set size) and ``VmHWM`` (its peak so far);
``smaps_rollup`` gives the proportional set size (``Pss``: each shared page split among the
processes that map it) and the private and shared pages (Linux 4.14 and later).
"""

from __future__ import annotations

import re
from pathlib import Path

#: the fields of smaps_rollup read (kB); PSS is Pss_Anon + Pss_File + Pss_Shmem
ROLLUP_FIELDS = ("Rss", "Pss", "Shared_Clean", "Shared_Dirty", "Private_Clean", "Private_Dirty", "Pss_Anon")


def memory_kb(pid: int | str = "self") -> dict[str, int]:
    """Process ``pid``'s memory (kB): ``VmRSS``, ``VmHWM`` and the :data:`ROLLUP_FIELDS` it
    reports (a field absent from its files is absent here). Raises OSError when the process is
    gone or there is no /proc (not Linux)."""
    proc = Path("/proc") / str(pid)
    status = (proc / "status").read_text()
    out = {}
    for name in ("VmRSS", "VmHWM"):
        match = re.search(rf"^{name}:\s+(\d+) kB", status, re.M)
        if match:
            out[name] = int(match.group(1))
    for line in (proc / "smaps_rollup").read_text().splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0].rstrip(":") in ROLLUP_FIELDS:
            out[parts[0].rstrip(":")] = int(parts[1])
    return out
