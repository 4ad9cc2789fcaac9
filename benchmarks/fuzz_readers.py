"""Fuzzed readers: every reader a user's file reaches, fed damaged copies of small real files.

    python benchmarks/fuzz_readers.py --count 500            # every format, 500 mutants each
    python benchmarks/fuzz_readers.py --count 200 --formats c3d,bvh --seed 3

Each format starts from small real files (the shipped recordings of benchmarks/recordings, the CMU clips and the
Qualisys calibration of ../shared/data, the project's catalogs and test motion files; where no real file of a
format exists, one derived from them: a TRC of a shipped C3D, a Pose2Sim toml and an OpenCV file of the Qualisys
cameras, a DeepMoCap view, a prior file). A seeded mutator damages one of its files (bit flips, inserted or deleted
bytes, truncation, duplicated chunks; numbers replaced by huge, negative, NaN or infinite values in text formats;
header and parameter fields changed in C3D) and the format's public reader (the one the CLI and the datasets call)
reads it in a worker process with a time limit and a cap on its address space. Each mutant must either read or
raise the project's own error (``MocapflowError``) naming the file; anything else is counted and its first
tracebacks printed:

    format      mutants  read  clean  unnamed  other  hangs  crashes
    c3d             500   123    377        0      0      0        0

``unnamed``: a project error whose message does not name the damaged file; ``other``: any other exception
(``MemoryError`` included: a size the file claims allocated before it was checked); ``hangs``: no answer within
``--timeout`` seconds; ``crashes``: the worker died (a segfault or an abort in native code). The exit status is 1
when any mutant is not clean. tests/formats/test_fuzz_readers.py runs a CI-sized share of the same mutants.

Only the standard library is imported at module level: the worker processes import the readers themselves.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import random
import re
import resource
import shutil
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOCAPFLOW_SHARED_DATA") or ROOT.parent / "shared" / "data")
MEMORY_LIMIT = 2 << 30  # bytes of address space a read may add to the worker's
TIMEOUT_S = 20.0
OUTCOMES = ("read", "clean", "unnamed", "other", "hangs", "crashes")


# ---- the mutator ---------------------------------------------------------------------------------
NUMBER = re.compile(rb"(?<![A-Za-z_])-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
ODD_NUMBERS = (b"1e308", b"-1e308", b"1e999", b"-1e999", b"-1", b"-0", b"0", b"nan", b"NaN", b"inf", b"-inf",
               b"99999999999999999999", b"4294967296", b"-2147483649", b"1e-320", b"2147483647", b"65535", b"", b"0x1f",
               b"1,5", b"1e9", b"-99999")


def mutate(data: bytes, rng: random.Random, kind: str) -> tuple[bytes, str]:
    """A damaged copy of ``data`` and what was done to it: 1 to 3 random operations (see the module docstring);
    ``kind``: "text", "binary" or "c3d" (which field mutations apply)."""
    out, done = bytearray(data), []
    for _ in range(rng.choice((1, 1, 1, 2, 3))):
        ops = [_bit_flip, _insert, _delete, _truncate, _duplicate]
        if kind == "text":
            ops += [_number, _number, _number, _line]
        elif kind == "c3d":
            ops += [_c3d_header, _c3d_header, _c3d_parameter, _c3d_parameter]
        op = rng.choice(ops)
        out, what = op(out, rng)
        done.append(what)
    return bytes(out), "; ".join(done)


def _at(data: bytearray, rng: random.Random) -> int:
    return rng.randrange(len(data)) if data else 0


def _bit_flip(data: bytearray, rng: random.Random):
    if not data:
        return data, "bit flip (empty)"
    i, bit = _at(data, rng), rng.randrange(8)
    data[i] ^= 1 << bit
    return data, f"bit {bit} of byte {i} flipped"


def _insert(data: bytearray, rng: random.Random):
    i, n = _at(data, rng), rng.choice((1, 1, 2, 4, 16, 64))
    junk = bytes(rng.randrange(256) for _ in range(n)) if rng.random() < 0.5 else \
        bytes(rng.choice(b" \t\n{}:-.0123456789eE#,[]()") for _ in range(n))
    return data[:i] + junk + data[i:], f"{n} byte(s) inserted at {i}"


def _delete(data: bytearray, rng: random.Random):
    i, n = _at(data, rng), rng.choice((1, 1, 2, 8, 64, 512))
    return data[:i] + data[i + n:], f"{n} byte(s) deleted at {i}"


def _truncate(data: bytearray, rng: random.Random):
    i = _at(data, rng) if rng.random() < 0.8 else rng.randrange(min(len(data), 64) + 1)
    return data[:i], f"truncated to {i} bytes"


def _duplicate(data: bytearray, rng: random.Random):
    i, n = _at(data, rng), rng.choice((8, 64, 512, 4096))
    chunk = data[i:i + n]
    j = i + len(chunk) if rng.random() < 0.5 else _at(data, rng)
    return data[:j] + chunk + data[j:], f"{len(chunk)} byte(s) at {i} copied to {j}"


def _number(data: bytearray, rng: random.Random):
    found = list(NUMBER.finditer(data))
    if not found:
        return _bit_flip(data, rng)
    match, value = rng.choice(found), rng.choice(ODD_NUMBERS)
    return data[:match.start()] + value + data[match.end():], \
        f"number {match.group().decode()!r} at {match.start()} -> {value.decode()!r}"


def _line(data: bytearray, rng: random.Random):
    lines = bytes(data).split(b"\n")
    i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
    what = rng.choice(("deleted", "duplicated", "swapped"))
    if what == "deleted":
        del lines[i]
    elif what == "duplicated":
        lines.insert(j, lines[i])
    else:
        lines[i], lines[j] = lines[j], lines[i]
    return bytearray(b"\n".join(lines)), f"line {i} {what}" + ("" if what == "deleted" else f" ({j})")


# C3D: header words 1-12 (bytes 0-23; 7-8 the scale and 11-12 the rate are floats) and the parameter section's
# first bytes (its block count, processor type) and records (name lengths, group ids, types, dimensions).
def _c3d_header(data: bytearray, rng: random.Random):
    if len(data) < 24:
        return _bit_flip(data, rng)
    if rng.random() < 0.3:
        at = rng.choice((12, 20))
        value = rng.choice((float("nan"), float("inf"), -1.0, 0.0, 1e30, -1e-30, 3.4e38))
        import struct
        data[at:at + 4] = struct.pack("<f", value)
        return data, f"header float at byte {at} -> {value}"
    word = rng.randrange(12)
    value = rng.choice((0, 1, 2, 0xFF, 0x7FFF, 0x8000, 0xFFFF, rng.randrange(0x10000)))
    if word == 0 and rng.random() < 0.5:  # the parameter block pointer and the 0x50 key, one byte each
        at = rng.randrange(2)
        data[at] = value & 0xFF
        return data, f"header byte {at} -> {value & 0xFF}"
    data[2 * word:2 * word + 2] = value.to_bytes(2, "little")
    return data, f"header word {word + 1} -> {value}"


def _c3d_parameter(data: bytearray, rng: random.Random):
    start = (data[0] - 1) * 512 if data and data[0] >= 1 else 512
    if len(data) < start + 8:
        return _bit_flip(data, rng)
    if rng.random() < 0.3:
        at = start + rng.choice((2, 3))
    else:
        at = start + 4 + rng.randrange(min(2048, len(data) - start - 4))
    value = rng.choice((0, 1, 0x7F, 0x80, 0xFF, rng.randrange(256)))
    data[at] = value
    return data, f"parameter byte {at} -> {value}"


# ---- the formats: base files and readers ----------------------------------------------------------
@dataclass
class Case:
    """One base recording of a format: its files (name -> bytes) and which of them a mutant damages."""

    name: str
    files: dict[str, bytes]
    targets: tuple[str, ...]
    kind: str = "text"  # of the damaged file: text, binary, c3d
    meta: dict = field(default_factory=dict)


def _shipped_c3d() -> list[Path]:
    return sorted((ROOT / "benchmarks" / "recordings").glob("*.c3d")) + \
        sorted((ROOT / "benchmarks" / "recordings" / "tuning").glob("*.c3d"))


def cases_c3d() -> list[Case]:
    return [Case(p.stem, {p.name: p.read_bytes()}, (p.name,), "c3d") for p in _shipped_c3d()]


def cases_trc() -> list[Case]:
    """TRC files of the shipped C3D recordings (their first 40 frames, as trc_text writes them)."""
    import numpy as np

    from mocapflow.formats import c3d, trc

    out = []
    for p in _shipped_c3d()[:4]:
        points, fps, names, _ = c3d.read_trajectories(p)
        points = points[:40]
        text = trc.trc_text(points, names, fps, np.arange(len(points)), "z", f"{p.stem}.trc")
        out.append(Case(p.stem, {f"{p.stem}.trc": text.encode()}, (f"{p.stem}.trc",)))
    return out


def _cut_bvh(text: str, frames: int) -> str:
    """A BVH clip's first ``frames`` frames."""
    head, motion = text.split("MOTION", 1)
    lines = motion.strip().splitlines()
    return head + "MOTION\n" + f"Frames: {frames}\n" + lines[1] + "\n" + "\n".join(lines[2:2 + frames]) + "\n"


def cases_bvh() -> list[Case]:
    """The CMU clips of ../shared/data (their first 30 frames); the tests' hand-written Mixamo clip without them."""
    clips = sorted((SHARED / "motions").glob("*.bvh")) if (SHARED / "motions").is_dir() else []
    out = [Case(p.stem, {p.name: _cut_bvh(p.read_text(), 30).encode()}, (p.name,)) for p in clips]
    if not out:
        sys.path.insert(0, str(ROOT / "tests"))
        from motion_files import mixamo_text

        out = [Case("mixamo", {"mixamo.bvh": mixamo_text().encode()}, ("mixamo.bvh",))]
    return out


def cases_asf_amc() -> list[Case]:
    """The tests' CMU-named ASF skeleton and AMC take (tests/motion_files.py); a mutant damages either."""
    sys.path.insert(0, str(ROOT / "tests"))
    from motion_files import cmu_amc_text, cmu_asf_text

    return [Case("cmu", {"subject.asf": cmu_asf_text().encode(), "take.amc": cmu_amc_text().encode()},
                 ("subject.asf", "take.amc"))]


def _qca() -> Path | None:
    path = SHARED / "calibration" / "pose2sim_demo_Calib.qca.txt"
    return path if path.is_file() else None


def cases_qca() -> list[Case]:
    path = _qca()
    return [Case("pose2sim_demo", {path.name: path.read_bytes()}, (path.name,))] if path else []


def _qca_views() -> dict:
    from mocapflow.formats.calibration import read_qca

    return read_qca(_qca()) if _qca() else {}


def cases_toml() -> list[Case]:
    """The Qualisys cameras as a Pose2Sim Calib.toml (metres)."""
    import cv2
    import numpy as np

    lines = []
    for k, (name, v) in enumerate(_qca_views().items(), 1):
        pose = np.asarray(v["cam_to_world"])
        rot = pose[:3, :3].T
        rvec = cv2.Rodrigues(rot)[0].ravel()
        tvec = -rot @ pose[:3, 3]
        lines += [f"[cam_{k}]", f'name = "{name}"', f"size = [ {v['width']:.1f}, {v['height']:.1f},]",
                  f"matrix = [ [ {v['fx']!r}, 0.0, {v['cx']!r},], [ 0.0, {v['fy']!r}, {v['cy']!r},], [ 0.0, 0.0, 1.0,],]",
                  f"distortions = [ {', '.join(repr(d) for d in v['dist'][:4])},]",
                  f"rotation = [ {', '.join(repr(float(x)) for x in rvec)},]",
                  f"translation = [ {', '.join(repr(float(x)) for x in tvec)},]", "fisheye = false", ""]
    if not lines:
        return []
    lines += ["[metadata]", "adjusted = false", "error = 0.0"]
    return [Case("pose2sim_demo", {"Calib.toml": "\n".join(lines).encode()}, ("Calib.toml",))]


def cases_opencv() -> list[Case]:
    """The first Qualisys camera as OpenCV FileStorage YAML and XML files (millimetres), as cv2.FileStorage writes
    them."""
    import cv2
    import numpy as np

    views = _qca_views()
    if not views:
        return []
    name, v = next(iter(views.items()))
    pose = np.asarray(v["cam_to_world"])
    rot = pose[:3, :3].T
    folder = Path(tempfile.mkdtemp())
    out = []
    for suffix in (".yml", ".xml"):
        path = folder / f"{name}{suffix}"
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        fs.write("image_width", int(v["width"]))
        fs.write("image_height", int(v["height"]))
        fs.write("camera_matrix", np.array([[v["fx"], 0, v["cx"]], [0, v["fy"], v["cy"]], [0, 0, 1]], np.float64))
        fs.write("distortion_coefficients", np.array(v["dist"], np.float64).reshape(1, 5))
        fs.write("R", rot)
        fs.write("T", (-rot @ pose[:3, 3] * 1000.0).reshape(3, 1))
        fs.release()
        out.append(Case(f"{name}{suffix}", {path.name: path.read_bytes()}, (path.name,)))
    shutil.rmtree(folder)
    return out


DMC_PREFIX = "take_D4_"
DMC_SIZE = (32, 24)


def cases_dmc() -> list[Case]:
    """One DeepMoCap view of two frames (extrinsics, 16-bit PGM depth, colorized depth with two reflectors black),
    the sensor 2 m back and 1 m up as the Kinect's axes put it; a mutant damages one of its files."""
    import cv2
    import numpy as np

    width, height = DMC_SIZE
    files = {"take/D4.extrinsics": b"-1.000 0.000 0.000\n0.000 0.000 1.000\n0.000 1.000 0.000\n0.0 -2000.0 1000.0\n"}
    for f in (1, 2):
        depth = (1500 + 40 * np.add.outer(np.arange(height), np.arange(width)) + 10 * f).astype(np.uint16)
        jet = cv2.applyColorMap(np.clip(depth / 4000.0 * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_JET)
        jet[10:12, 8 + f:10 + f] = 0
        ok, pgm = cv2.imencode(".pgm", depth)
        ok2, png = cv2.imencode(".png", jet)
        assert ok and ok2
        files[f"take/D4/{DMC_PREFIX}{f:05d}depth.pgm"] = pgm.tobytes()
        files[f"take/D4/{DMC_PREFIX}{f:05d}mc_blob.png"] = png.tobytes()
    return [Case("extrinsics", files, ("take/D4.extrinsics",), "text"),
            Case("depth", files, tuple(k for k in files if k.endswith(".pgm")), "text"),
            Case("colour", files, tuple(k for k in files if k.endswith(".png")), "binary")]


def _prior_joints():
    """A prior's joints: the template body at rest, walking 1 m/s along +Y for 12 frames at 30 fps, frame 3 lost."""
    import numpy as np

    from mocapflow.tasks.shared import body

    offsets = body.rest_offsets(body.Subject())
    rest = np.zeros_like(offsets)
    for j, parent in enumerate(body.PARENTS):  # parents come first
        rest[j] = offsets[j] + (rest[parent] if parent >= 0 else 0.0)
    joints = rest[None] + np.arange(12)[:, None, None] * np.array([0.0, 1.0 / 30, 0.0])
    joints[3] = np.nan
    return joints


def cases_prior() -> list[Case]:
    import io
    import json

    import numpy as np

    from mocapflow.tasks.shared.body import JOINT_NAMES

    joints = _prior_joints()
    doc = {"joints": [None if not np.isfinite(f).all() else f.round(5).tolist() for f in joints], "fps": 30,
           "joint_names": list(JOINT_NAMES), "up": "z", "unit": "m"}
    doc["joints"] = [f if f is not None else [[None] * 3] * 20 for f in doc["joints"]]
    buf = io.BytesIO()
    np.savez(buf, joints=joints, fps=np.float64(30.0), joint_names=np.array(JOINT_NAMES), up="z", unit="m")
    meta = {"frames": len(joints), "fps": 30.0}
    return [Case("json", {"take.json": json.dumps(doc, indent=1).encode()}, ("take.json",), "text", meta),
            Case("npz", {"take.npz": buf.getvalue()}, ("take.npz",), "binary", meta)]


def cases_catalog() -> list[Case]:
    """The project's catalogs that name no shared data (catalog.yaml, benchmarks/*.yaml)."""
    paths = [ROOT / "catalog.yaml"] + sorted((ROOT / "benchmarks").glob("*.yaml"))
    out = []
    for p in paths:
        text = p.read_text()
        if "shared/data" in text or "plugins" in text:
            continue
        out.append(Case(p.stem, {"catalog.yaml": text.encode()}, ("catalog.yaml",)))
    return out[:6]


def read_c3d(folder: Path, case: Case):
    from mocapflow.systems.uuo.marker_files import read_markers

    read_markers(folder / case.targets[0], labels="use")


def read_bvh(folder: Path, case: Case):
    from mocapflow.formats.bvh import read_bvh_joints

    read_bvh_joints(folder / case.targets[0])


def read_studio(folder: Path, case: Case):
    """The studio's door: a catalog sequence naming the file (a BVH clip, or an AMC take and its ASF skeleton)."""
    from mocapflow.systems.studio.specs import make_spec

    files = {Path(n).suffix: folder / n for n in case.files}
    raw = {"motion": str(files[".amc"]), "skeleton": str(files[".asf"]), "fps": 120.0} if ".amc" in files else \
        {"motion": str(files[".bvh"])}
    make_spec(raw, "datasets.fuzz.sequences.take", lambda p: Path(p))


def read_calibration_as(fmt: str):
    def read(folder: Path, case: Case):
        from mocapflow.formats.calibration import read_calibration

        read_calibration(folder / case.targets[0], fmt, unit="mm" if fmt == "opencv" else None)
    return read


def read_dmc(folder: Path, case: Case):
    """The dmc dataset's door (describe: extrinsics, headers, the first colorized depth) and its frames (read)."""
    from mocapflow.pipeline.catalog import DatasetConfig
    from mocapflow.systems.deepmocap import dmc_files

    width, height = DMC_SIZE
    dataset = DatasetConfig("fuzz", "dmc", {"intrinsics": {"fx": 30.0, "fy": 30.0, "cx": width / 2, "cy": height / 2}},
                            "catalog.yaml (line 1): datasets.fuzz")
    views, n_frames, _ = dmc_files.describe(dataset, folder / "take")
    dmc_files.read(views, True, 30.0, 0, n_frames)


def read_prior(folder: Path, case: Case):
    from mocapflow.systems.uuo.prior_files import read_prior as read

    read(folder / case.targets[0], frames=case.meta["frames"], fps=case.meta["fps"])


def read_catalog(folder: Path, case: Case):
    from mocapflow.pipeline.catalog import load_catalog

    load_catalog(folder / "catalog.yaml")


@dataclass(frozen=True)
class Format:
    cases: object  # () -> list[Case]
    read: object  # (folder, case) -> None


FORMATS = {
    "c3d": Format(cases_c3d, read_c3d),
    "trc": Format(cases_trc, read_c3d),
    "bvh": Format(cases_bvh, read_bvh),
    "bvh_studio": Format(cases_bvh, read_studio),
    "asf_amc": Format(cases_asf_amc, read_studio),
    "qca": Format(cases_qca, read_calibration_as("qca")),
    "toml": Format(cases_toml, read_calibration_as("toml")),
    "opencv": Format(cases_opencv, read_calibration_as("opencv")),
    "dmc": Format(cases_dmc, read_dmc),
    "prior": Format(cases_prior, read_prior),
    "catalog": Format(cases_catalog, read_catalog),
}


# ---- the worker: reads a mutant under a time limit and a memory cap --------------------------------
def _address_space() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[0]) * resource.getpagesize()


def _worker(conn, memory_limit: int, formats: list[str]) -> None:
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    sys.path.insert(0, str(ROOT / "tests"))
    import warnings

    warnings.simplefilter("ignore")
    from mocapflow.pipeline.errors import MocapflowError

    for name in formats:  # every import a reader makes, before the cap
        fmt = FORMATS[name]
        for case in fmt.cases():
            folder = Path(tempfile.mkdtemp(prefix="fuzz-warm-"))
            try:
                write_case(folder, case.files)
                fmt.read(folder, case)
            except Exception:  # a base file that does not read is reported by the parent's own check
                pass
            finally:
                shutil.rmtree(folder, ignore_errors=True)
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = _address_space() + memory_limit
    resource.setrlimit(resource.RLIMIT_AS, (cap if hard == resource.RLIM_INFINITY else min(cap, hard), hard))
    conn.send("ready")
    while True:
        job = conn.recv()
        if job is None:
            return
        name, folder, case, damaged = job
        try:
            FORMATS[name].read(Path(folder), case)
            conn.send(("read", ""))
        except MocapflowError as exc:
            message = str(exc)
            named = Path(damaged).name in message
            conn.send(("clean" if named else "unnamed", f"{type(exc).__name__}: {message}"))
        except BaseException as exc:  # noqa: BLE001 - what the fuzzer is here to find
            conn.send(("other", "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))))


def write_case(folder: Path, files: dict[str, bytes]) -> None:
    for name, data in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(data)


class Pool:
    """One worker process (spawned, the readers imported once, its address space capped); a read that does not
    answer within ``timeout`` s is a hang, a worker that dies a crash: either way a fresh worker takes over."""

    def __init__(self, formats: list[str], *, timeout: float = TIMEOUT_S, memory_limit: int = MEMORY_LIMIT):
        self.formats, self.timeout, self.memory_limit = formats, timeout, memory_limit
        self.ctx = mp.get_context("spawn")
        self.proc = self.conn = None

    def _start(self) -> None:
        self.conn, child = self.ctx.Pipe()
        self.proc = self.ctx.Process(target=_worker, args=(child, self.memory_limit, self.formats), daemon=True)
        self.proc.start()
        child.close()
        if not self.conn.poll(600) or self.conn.recv() != "ready":
            raise RuntimeError("the fuzz worker did not start")

    def _stop(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.join()
        self.proc = None

    def read(self, name: str, folder: Path, case: Case, damaged: str) -> tuple[str, str]:
        if self.proc is None or not self.proc.is_alive():
            self._start()
        self.conn.send((name, str(folder), case, damaged))
        try:
            if self.conn.poll(self.timeout):
                return self.conn.recv()
        except EOFError:
            pass
        alive = self.proc.is_alive()
        self._stop()
        if alive:
            return "hangs", f"no answer within {self.timeout:g} s"
        return "crashes", "the worker died"

    def close(self) -> None:
        if self.proc is not None and self.proc.is_alive():
            try:
                self.conn.send(None)
                self.proc.join(5)
            except (BrokenPipeError, OSError):
                pass
        self._stop()


@dataclass
class Result:
    name: str
    counts: dict = field(default_factory=lambda: dict.fromkeys(OUTCOMES, 0))
    failures: list = field(default_factory=list)  # (mutant description, outcome, detail)
    seconds: float = 0.0


def mutants(name: str, count: int, seed: int):
    """``count`` mutants of format ``name``: (case, damaged file, damaged bytes, what was done), the same for a
    seed."""
    cases = FORMATS[name].cases()
    rng = random.Random(f"{seed}:{name}")
    for k in range(count):
        case = cases[k % len(cases)] if cases else None
        if case is None:
            return
        target = case.targets[rng.randrange(len(case.targets))]
        data, what = mutate(case.files[target], rng, case.kind)
        yield case, target, data, what


def fuzz(name: str, count: int, seed: int, pool: Pool, work: Path) -> Result:
    """Read ``count`` mutants of format ``name`` through ``pool``."""
    result = Result(name)
    start = time.perf_counter()
    for k, (case, target, data, what) in enumerate(mutants(name, count, seed)):
        folder = work / f"{name}-{k}"
        write_case(folder, {**case.files, target: data})
        outcome, detail = pool.read(name, folder, case, target)
        result.counts[outcome] += 1
        if outcome not in ("read", "clean"):
            result.failures.append((f"{name} #{k} {case.name}/{target}: {what}", outcome, detail))
        shutil.rmtree(folder, ignore_errors=True)
    result.seconds = time.perf_counter() - start
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=500, help="mutants per format")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--formats", default=",".join(FORMATS), help=f"comma-separated, of {', '.join(FORMATS)}")
    parser.add_argument("--timeout", type=float, default=TIMEOUT_S, help="seconds a read may take")
    parser.add_argument("--tracebacks", type=int, default=3, help="failures shown per format")
    args = parser.parse_args(argv)
    names = [n for n in args.formats.split(",") if n]
    unknown = [n for n in names if n not in FORMATS]
    if unknown:
        parser.error(f"unknown formats {unknown}; known: {', '.join(FORMATS)}")
    sys.path.insert(0, str(ROOT / "tests"))
    pool = Pool(names, timeout=args.timeout)
    results = []
    with tempfile.TemporaryDirectory(prefix="fuzz-readers-") as tmp:
        try:
            for name in names:
                results.append(fuzz(name, args.count, args.seed, pool, Path(tmp)))
                r = results[-1]
                print(f"{name}: {sum(r.counts.values())} mutants in {r.seconds:.1f} s", file=sys.stderr, flush=True)
        finally:
            pool.close()
    print(f"{'format':<12}{'mutants':>8}" + "".join(f"{o:>9}" for o in OUTCOMES) + f"{'s':>7}")
    for r in results:
        print(f"{r.name:<12}{sum(r.counts.values()):>8}" + "".join(f"{r.counts[o]:>9}" for o in OUTCOMES)
              + f"{r.seconds:>7.1f}")
    bad = False
    for r in results:
        for what, outcome, detail in r.failures[:args.tracebacks]:
            bad = True
            print(f"\n--- {outcome}: {what}\n{detail.rstrip()}")
        bad |= bool(r.failures)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
