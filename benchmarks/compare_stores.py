"""Compare two storage roots artifact by artifact, bit for bit.

    python benchmarks/compare_stores.py ROOT_A ROOT_B [--stage NAME ...]

Each complete version is matched by (stage, partition), not by cache key, so stores written by two
versions of the code (whose keys may differ) compare; where a root holds several complete versions of
one partition, the newest is taken. Every data variable and coordinate is compared as raw values (NaN
equal to NaN). Prints one line per stage and a summary; exits 1 when anything differs or is missing.
Use it to show that a refactor or a speed change leaves the outputs untouched.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import xarray as xr


def complete_versions(root: Path) -> dict[tuple[str, str], Path]:
    """(stage, partition) -> the newest complete version folder under ``root``."""
    found: dict[tuple[str, str], Path] = {}
    for complete in sorted(root.glob("*/*/_COMPLETE"), key=lambda p: p.stat().st_mtime):
        version = complete.parent
        lineage = json.loads((version / "lineage.json").read_text())
        found[(version.parent.name, lineage["partition"])] = version
    return found


def differences(a: xr.Dataset, b: xr.Dataset) -> list[str]:
    """Names of the variables and coordinates whose values, shapes or dtypes differ between a and b."""
    names_a, names_b = set(a.variables), set(b.variables)
    out = sorted(f"{n} (only in one)" for n in names_a ^ names_b)
    for name in sorted(names_a & names_b):
        x, y = a[name].values, b[name].values
        same = x.shape == y.shape and x.dtype == y.dtype and (
            np.array_equal(x, y, equal_nan=x.dtype.kind in "fc"))
        if not same:
            out.append(name)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root_a", type=Path)
    parser.add_argument("root_b", type=Path)
    parser.add_argument("--stage", action="append", help="compare only these stages (repeatable)")
    args = parser.parse_args(argv)
    a, b = complete_versions(args.root_a), complete_versions(args.root_b)
    wanted = set(args.stage or {s for s, _ in a} | {s for s, _ in b})
    identical = differing = missing = 0
    for stage in sorted(wanted):
        parts = sorted({p for s, p in a if s == stage} | {p for s, p in b if s == stage})
        bad = []
        for part in parts:
            if (stage, part) not in a or (stage, part) not in b:
                missing += 1
                bad.append(f"{part}: missing in {'A' if (stage, part) not in a else 'B'}")
                continue
            with xr.open_zarr(a[stage, part] / "data.zarr", consolidated=False) as x, \
                    xr.open_zarr(b[stage, part] / "data.zarr", consolidated=False) as y:
                diff = differences(x, y)
            if diff:
                differing += 1
                bad.append(f"{part}: {', '.join(diff)}")
            else:
                identical += 1
        print(f"{stage}: {len(parts) - len(bad)}/{len(parts)} identical" + "".join(f"\n  {line}" for line in bad))
    print(f"{identical} identical, {differing} differing, {missing} missing")
    return 0 if differing == missing == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
