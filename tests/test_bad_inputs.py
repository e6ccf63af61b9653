"""The bad-input battery: every input surface, through the real command line.

One line per case: an id, the command line (run in a fresh temporary directory, relative paths),
the files the case puts there first, and the words the error must contain (the file, field, row
or value it names). Every case must end with exit code 2, no traceback, the named culprit in the
message, and the temporary directory byte-identical to how the case left it (no output, no
staging litter). A case that cannot pass yet is marked with ``owner`` and ``why`` and runs as
``xfail(strict=True)``, so it turns into an error the day it is fixed (none is marked today).

Commands run in-process (``plm_highway.cli.main``), so the battery costs seconds, not minutes:
each case is refused before any long work starts.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from plm_highway.cli import main

REPO_ROOT = Path(__file__).resolve().parent.parent
SHIPPED_CKPT = REPO_ROOT / "plm_highway" / "checkpoints"

# -- fixtures built once: a valid track, dataset, recording, checkpoint pair ------------------------

TRACK = {"name": "t", "lanes": 3, "lane_width_m": 4.0,
         "segments": [{"type": "straight", "length_m": 100},
                      {"type": "arc", "radius_m": 100, "angle_deg": 30, "direction": "left"}]}


@pytest.fixture(scope="module")
def fixtures(tmp_path_factory) -> dict[str, Path]:
    """name -> a valid input of that kind, copied into a case's directory by :class:`Copy`."""
    from plm_highway.data.collect import collect
    from plm_highway.data.dataset import write_dataset
    from plm_highway.sim2real.physics.synth import make_recording
    from plm_highway.sim2real.record.recording import write_recording

    root = tmp_path_factory.mktemp("valid_inputs")
    frames, steps, manifest = collect(track="test", episodes=1, episode_seconds=1, progress=False)
    write_dataset(root / "ds", frames, steps, manifest)
    ckpt = root / "ck"
    for name, stem in (("bm", "bm_default"), ("tapm", "tapm_default")):
        (ckpt / name).mkdir(parents=True)
        shutil.copy(SHIPPED_CKPT / f"{stem}.pt", ckpt / name / "model.pt")
        shutil.copy(SHIPPED_CKPT / f"{stem}.json", ckpt / name / "model.json")
    (root / "rec").mkdir()
    recording, truth = make_recording({}, rng=np.random.default_rng(0), duration_s=30.0)
    write_recording(recording, root / "rec" / "r.csv", truth=truth)
    return {"ds": root / "ds", "ck": ckpt, "rec": root / "rec"}


@dataclass(frozen=True)
class Copy:
    """A valid fixture input copied to the case's path, then changed by ``then(path)``."""

    fixture: str
    then: Callable[[Path], None] | None = None


@dataclass(frozen=True)
class Case:
    id: str
    argv: tuple[str, ...]
    names: tuple[str, ...]  # each must appear in stderr
    files: dict = field(default_factory=dict)  # relative path -> str | bytes | dict/list (JSON) | Copy
    owner: str | None = None  # a known gap, named by its room: xfail(strict) until it is fixed
    why: str = ""
    timeout_s: float = 120  # a case that today runs the whole command instead of refusing it is cut short


def c(case_id, argv, names, files=None, owner=None, why="", timeout_s=120):
    names = (names,) if isinstance(names, str) else tuple(names)
    argv = tuple(argv.split()) if isinstance(argv, str) else tuple(argv)
    return Case(case_id, argv, names, files or {}, owner, why, timeout_s)


# -- file makers ----------------------------------------------------------------------------------


def track_with(**changes) -> dict:
    return {**TRACK, **changes}


def segment(**fields_) -> dict:
    return track_with(segments=[fields_])


def edit_json(relative: str, change: Callable[[dict], object]) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        path = root / relative
        data = json.loads(path.read_text())
        result = change(data)
        path.write_text(json.dumps(data if result is None else result))
    return apply


def write_bytes(relative: str, data: bytes) -> Callable[[Path], None]:
    return lambda root: (root / relative).write_bytes(data)


def truncate(relative: str, keep_fraction: float = 0.5) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        path = root / relative
        data = path.read_bytes()
        path.write_bytes(data[:int(len(data) * keep_fraction)])
    return apply


class _Marker:
    """Unpickling this calls open(marker, 'w'): the file appears if anything executes the pickle."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


MARKER = "PICKLE_WAS_EXECUTED"


def malicious_pickle(relative: str) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        import torch

        marker = str(root.parent / MARKER)  # outside the copied input: absolute, in the case's directory
        torch.save({"weight": _Marker(marker)}, root / relative)
    return apply


def malicious_npy(relative: str) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        marker = str(root.parent / MARKER)
        with open(root / relative, "wb") as handle:
            np.lib.format.write_array(handle, np.array([_Marker(marker)], dtype=object), allow_pickle=True)
    return apply


def foreign_state_dict(relative: str) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        import torch

        torch.save(torch.nn.Sequential(torch.nn.Conv2d(3, 8, 3), torch.nn.Linear(8, 1)).state_dict(), root / relative)
    return apply


def other_model_weights(relative: str, source: str) -> Callable[[Path], None]:
    """The weights of the other model of the pair (a TAPM state_dict where a BM goes)."""
    return lambda root: shutil.copy(root / source, root / relative)


def perturbed_weights(relative: str, value: float) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        import torch

        state = torch.load(root / relative, weights_only=True)
        key = next(iter(state))
        state[key] = torch.full_like(state[key], value)
        torch.save(state, root / relative)
    return apply


def steps_column(column: str, change: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        path = root / "steps.npz"
        with np.load(path) as data:
            steps = {key: data[key] for key in data.files}
        steps[column] = change(steps[column])
        with open(path, "wb") as handle:
            np.savez(handle, **steps)
    return apply


def frames_as(change: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        frames = np.load(root / "frames.npy")
        np.save(root / "frames.npy", change(frames))
    return apply


def recording_rows(change: Callable[[list[list[str]]], list[list[str]]]) -> Callable[[Path], None]:
    """Change the recording CSV's rows (header first) as lists of cells."""
    def apply(root: Path) -> None:
        path = root / "r.csv"
        rows = [line.split(",") for line in path.read_text().splitlines()]
        path.write_text("\n".join(",".join(row) for row in change(rows)) + "\n")
    return apply


def set_column(name: str, value: str, rows_slice=slice(1, None)):
    def change(rows):
        index = rows[0].index(name)
        for row in rows[rows_slice]:
            row[index] = value
        return rows
    return change


def set_cell(name: str, row: int, value: str):
    return set_column(name, value, slice(row, row + 1))


def sidecar(**changes) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        (root / "r.json").write_text(json.dumps(changes))
    return apply


def sparse_file(size_bytes: int) -> Callable[[Path], None]:
    def apply(path: Path) -> None:
        with open(path, "wb") as handle:
            handle.truncate(size_bytes)
    return apply


class Make:
    """A file made by a function of its path (large or special files)."""

    def __init__(self, make: Callable[[Path], None]):
        self.make = make


DS = Copy("ds")


def edit_steps(column: str, row: int, value) -> Callable[[Path], None]:
    def apply(root: Path) -> None:
        import numpy as np

        with np.load(root / "steps.npz") as npz:
            steps = {name: npz[name].copy() for name in npz.files}
        steps[column][row] = value
        np.savez(root / "steps.npz", **steps)
    return apply
CK = Copy("ck")
REC = Copy("rec")
COLLECT = "collect --episodes 1 --episode-seconds 1 --out out"
EVAL = "evaluate --policy expert --max-steps 1 --json out.json"
EVAL_PLM = "evaluate --policy plm --max-steps 1 --json out.json --checkpoints ck"
TRAIN = "train bm --data ds --out out --epochs 1 --quiet"
TAPM = "train tapm --data ds --bm ck/bm --out out --epochs 1 --quiet"
DIAG = "sim2real diagnose rec/r.csv --quiet --json out.json"
MAKE_REC = "sim2real make-recording --duration-s 20 --out out.csv"
NESTED = "[" * 100_000 + "]" * 100_000
SWEEP = "sweep --out sw --workers 0 --no-progress --max-steps 1 --policy expert"
# 400 bytes of YAML whose aliases stand for 9**9 (387 million) strings once expanded.
ALIAS_BOMB = "\n".join(["a: &a [x, x, x, x, x, x, x, x, x]"]
                       + [f"{n}: &{n} [*{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}]"
                          for p, n in zip("abcdefgh", "bcdefghi")] + ["latencies: *i", ""])


def trace_rows(text: str) -> dict:
    return {"trace.csv": text}


CASES = [
    # -- track JSON (collect and evaluate read the same loader) ----------------------------------
    c("track-missing", f"{COLLECT} --track nosuch.json", "nosuch.json"),
    c("track-directory", f"{COLLECT} --track tdir", "tdir", {"tdir/x": "x"}),
    c("track-not-json", f"{COLLECT} --track t.json", ["t.json", "JSON"], {"t.json": "{"}),
    c("track-empty-file", f"{COLLECT} --track t.json", "t.json", {"t.json": ""}),
    c("track-binary", f"{COLLECT} --track t.json", "t.json", {"t.json": b"\xff\xfe\x00\x81garbage"}),
    c("track-bom", f"{COLLECT} --track t.json", "t.json", {"t.json": b"\xef\xbb\xbf{"}),
    c("track-list", f"{COLLECT} --track t.json", ["t.json", "object"], {"t.json": [TRACK]}),
    c("track-no-segments", f"{COLLECT} --track t.json", ["t.json", "segments"], {"t.json": {"name": "t"}}),
    c("track-segments-empty", f"{COLLECT} --track t.json", "segments", {"t.json": track_with(segments=[])}),
    c("track-segments-not-list", f"{COLLECT} --track t.json", "segments", {"t.json": track_with(segments="x")}),
    c("track-unknown-key", f"{COLLECT} --track t.json", "colour", {"t.json": track_with(colour="red")}),
    c("track-segment-type", f"{EVAL} --track t.json", ["segment 0", "type"],
      {"t.json": segment(type="spiral", length_m=5)}),
    c("track-length-negative", f"{COLLECT} --track t.json", ["segment 0", "length_m"],
      {"t.json": segment(type="straight", length_m=-5)}),
    c("track-length-string", f"{COLLECT} --track t.json", ["segment 0", "length_m"],
      {"t.json": segment(type="straight", length_m="50")}),
    c("track-length-1e12", f"{COLLECT} --track t.json", ["length_m"],
      {"t.json": segment(type="straight", length_m=1e12)}),
    c("track-length-1e300", f"{EVAL} --track t.json", ["length_m"],
      {"t.json": segment(type="straight", length_m=1e300)}),
    c("track-length-nan", f"{COLLECT} --track t.json", ["length_m"],
      {"t.json": '{"name": "t", "segments": [{"type": "straight", "length_m": NaN}]}'}),
    c("track-radius-tight", f"{COLLECT} --track t.json", ["segment 1", "radius_m"],
      {"t.json": track_with(segments=[TRACK["segments"][0],
                                      {"type": "arc", "radius_m": 5, "angle_deg": 90, "direction": "left"}])}),
    c("track-arc-direction", f"{COLLECT} --track t.json", ["segment 0", "direction"],
      {"t.json": segment(type="arc", radius_m=100, angle_deg=30, direction="up")}),
    c("track-arc-360-open", f"{COLLECT} --track t.json", ["t.json", "overlaps itself", "segment 0"],
      {"t.json": segment(type="arc", radius_m=100, angle_deg=360, direction="left")}),
    c("track-lanes-zero", f"{COLLECT} --track t.json", "lanes", {"t.json": track_with(lanes=0)}),
    c("track-lanes-huge", f"{COLLECT} --track t.json", "lanes", {"t.json": track_with(lanes=10**6)}),
    c("track-lane-width-zero", f"{COLLECT} --track t.json", "lane_width_m", {"t.json": track_with(lane_width_m=0)}),
    c("track-closed-not-closing", f"{COLLECT} --track t.json", ["t.json", "close"],
      {"t.json": track_with(closed=True)}),
    c("track-closed-string", f"{COLLECT} --track t.json", "closed", {"t.json": track_with(closed="yes")}),
    c("track-name-not-string", f"{COLLECT} --track t.json", "name", {"t.json": track_with(name=["x"])}),
    c("track-nested-brackets", f"{COLLECT} --track t.json", "t.json", {"t.json": NESTED}),
    c("track-many-tiny-segments", f"{EVAL} --track t.json", ["t.json", "larger than a track file may be"],
      {"t.json": track_with(segments=[{"type": "straight", "length_m": 0.01}] * 300_000)}, timeout_s=10),
    c("track-unknown-shipped-name", f"{EVAL} --track nosuch", "nosuch"),
    # -- latency specs (evaluate, demo, bench env parse the same specs) --------------------------
    c("latency-empty", [*EVAL.split(), "--latency", ""], "latency"),
    c("latency-blank", [*EVAL.split(), "--latency", "   "], "latency"),
    c("latency-not-number", f"{EVAL} --latency const:abc", "const:abc"),
    c("latency-negative", f"{EVAL} --latency const:-1", "const:-1"),
    c("latency-too-large", f"{EVAL} --latency const:100", "const:100"),
    c("latency-nan", f"{EVAL} --latency const:nan", "const:nan"),
    c("latency-inf", f"{EVAL} --latency const:inf", "const:inf"),
    c("latency-unknown-kind", f"{EVAL} --latency gauss:0.1", "gauss:0.1"),
    c("latency-steps-reversed", f"{EVAL} --latency steps:0.3-0.1:1", "steps:0.3-0.1:1"),
    c("latency-steps-tiny-period", f"{EVAL} --latency steps:0-0.3:1e-9", "steps:0-0.3:1e-9"),
    c("latency-steps-missing-field", f"{EVAL} --latency steps:0-0.3", "steps:0-0.3"),
    c("latency-frames-zero-every", f"{EVAL} --latency frames:0-0.3:0@30", "frames:0-0.3:0@30"),
    c("latency-frames-huge-rate", f"{EVAL} --latency frames:0-0.3:2@1e9", "frames:0-0.3:2@1e9"),
    c("latency-sine-negative", f"{EVAL} --latency sine:0.1:0.5:1", "sine:0.1:0.5:1"),
    c("latency-control-char", [*EVAL.split(), "--latency", "const:0.1\x00"], "control character"),
    c("latency-too-long", [*EVAL.split(), "--latency", "const:" + "1" * 5000], "characters"),
    c("latency-demo-bad", "demo zigzag --policy expert --out z.png --latency steps:1-0:1", "steps:1-0:1"),
    c("latency-bench-env-bad", "bench env --steps 50 --repeats 1 --latency const:x", "const:x"),
    # -- latency trace files ---------------------------------------------------------------------
    c("trace-missing", f"{EVAL} --latency trace:nosuch.csv", "nosuch.csv"),
    c("trace-directory", f"{EVAL} --latency trace:tdir", "tdir", {"tdir/x": "x"}),
    c("trace-empty", f"{EVAL} --latency trace:trace.csv", "trace.csv", trace_rows("")),
    c("trace-header-only", f"{EVAL} --latency trace:trace.csv", "trace.csv", trace_rows("t,latency_s\n")),
    c("trace-wrong-header", f"{EVAL} --latency trace:trace.csv", ["trace.csv", "missing columns"],
      trace_rows("t_s,latency_s\n0,0.1\n")),
    c("trace-latency-too-large", f"{EVAL} --latency trace:trace.csv", ["trace.csv", "latency_s", "99"],
      trace_rows("t,latency_s\n0,0.1\n1,99\n")),
    c("trace-not-number", f"{EVAL} --latency trace:trace.csv", ["trace.csv", "abc"],
      trace_rows("t,latency_s\n0,0.1\n1,abc\n")),
    c("trace-negative-latency", f"{EVAL} --latency trace:trace.csv", ["trace.csv", "-0.5"],
      trace_rows("t,latency_s\n0,0.1\n1,-0.5\n")),
    c("trace-time-backwards", f"{EVAL} --latency trace:trace.csv", "trace.csv",
      trace_rows("t,latency_s\n0,0.1\n2,0.1\n1,0.1\n")),
    c("trace-nan", f"{EVAL} --latency trace:trace.csv", "trace.csv", trace_rows("t,latency_s\n0,0.1\n1,nan\n")),
    c("trace-binary", f"{EVAL} --latency trace:trace.csv", "trace.csv", {"trace.csv": b"\x00\xff\xfe\x81\x00"}),
    c("trace-too-large", f"{EVAL} --latency trace:trace.csv", "trace.csv",
      {"trace.csv": Make(sparse_file(40 * 1024 * 1024))}),
    c("trace-missing-column", f"{EVAL} --latency trace:trace.csv", "trace.csv", trace_rows("t_s\n0\n1\n")),
    # -- recordings and sidecars -----------------------------------------------------------------
    c("rec-missing", "sim2real diagnose nosuch.csv --quiet", "nosuch.csv"),
    c("rec-directory", "sim2real diagnose rdir --quiet", "rdir", {"rdir/x": "x"}),
    c("rec-empty", "sim2real diagnose e.csv --quiet", "e.csv", {"e.csv": ""}),
    c("rec-binary", "sim2real diagnose e.csv --quiet", "e.csv", {"e.csv": b"\xff\xfe\x00garbage\x81"}),
    c("rec-header-only", "sim2real diagnose e.csv --quiet", "e.csv", {"e.csv": "t,steer,speed,x,y,heading\n"}),
    c("rec-missing-column", DIAG, ["r.csv", "steer"],
      {"rec": Copy("rec", recording_rows(lambda rows: [row[:1] + row[2:] for row in rows]))}),
    c("rec-not-number", DIAG, ["r.csv", "speed", "line 6"], {"rec": Copy("rec", recording_rows(set_cell("speed", 5, "fast")))}),
    c("rec-nan", DIAG, ["r.csv", "x"], {"rec": Copy("rec", recording_rows(set_cell("x", 7, "nan")))}),
    c("rec-time-backwards", DIAG, ["r.csv", "t"], {"rec": Copy("rec", recording_rows(set_cell("t", 9, "0")))}),
    c("rec-too-short", DIAG, ["r.csv", "s"], {"rec": Copy("rec", recording_rows(lambda rows: rows[:100]))}),
    c("rec-speed-zero", DIAG, ["r.csv", "speed"], {"rec": Copy("rec", recording_rows(set_column("speed", "0")))}),
    c("rec-one-huge-field", "sim2real diagnose big.csv --quiet", "big.csv", {"big.csv": Make(sparse_file(1 << 20))}),
    c("sidecar-not-json", DIAG, "r.json", {"rec": Copy("rec", write_bytes("r.json", b"{wheelbase"))}),
    c("sidecar-list", DIAG, "r.json", {"rec": Copy("rec", write_bytes("r.json", b"[1, 2]"))}),
    c("sidecar-wheelbase-negative", DIAG, "wheelbase_m", {"rec": Copy("rec", sidecar(wheelbase_m=-2.5))}),
    c("sidecar-wheelbase-string", DIAG, "wheelbase_m", {"rec": Copy("rec", sidecar(wheelbase_m="2.5"))}),
    c("sidecar-wheelbase-tiny", DIAG, "wheelbase_m", {"rec": Copy("rec", sidecar(wheelbase_m=1e-9))}, timeout_s=10),
    c("sidecar-cg-beyond-wheelbase", DIAG, ["r.json", "wheelbase"],
      {"rec": Copy("rec", sidecar(wheelbase_m=2.5, cg_to_front_m=4.0))}),
    c("sidecar-option-missing", f"{DIAG} --sidecar nosuch.json", "nosuch.json", {"rec": REC}),
    # -- sim2real options ------------------------------------------------------------------------
    c("diag-anchor-zero", f"{DIAG} --anchor-s 0", "--anchor-s", {"rec": REC}),
    c("diag-anchor-nan", f"{DIAG} --anchor-s nan", "--anchor-s", {"rec": REC}),
    c("diag-block-negative", f"{DIAG} --block-s -1", "--block-s", {"rec": REC}),
    c("diag-block-longer-than-recording", f"{DIAG} --block-s 1000", "--block-s", {"rec": REC}),
    c("diag-steer-scale-nan", f"{DIAG} --steer-column steer --steer-scale nan", "--steer-scale", {"rec": REC}),
    c("diag-steer-scale-zero", f"{DIAG} --steer-column steer --steer-scale 0", "--steer-scale", {"rec": REC}),
    c("diag-steer-column-unknown", f"{DIAG} --steer-column wheel", "wheel", {"rec": REC}),
    c("diag-json-onto-recording", "sim2real diagnose rec/r.csv --quiet --json rec/r.csv", "r.csv", {"rec": REC}),
    c("diag-split-choice", f"{DIAG} --split thirds", "thirds", {"rec": REC}),
    c("mkrec-duration-zero", f"{MAKE_REC} --duration-s 0", "duration"),
    c("mkrec-duration-huge", "sim2real make-recording --duration-s 1e12 --out out.csv", "duration"),
    c("mkrec-duration-nan", "sim2real make-recording --duration-s nan --out out.csv", "duration"),
    c("mkrec-rate-zero", f"{MAKE_REC} --rate-hz 0", "--rate-hz"),
    c("mkrec-rate-huge", f"{MAKE_REC} --rate-hz 1e9", "rate"),
    c("mkrec-noise-negative", f"{MAKE_REC} --noise-scale -1", "--noise-scale"),
    c("mkrec-effect-unknown", f"{MAKE_REC} --effect warp_drive", "warp_drive"),
    c("mkrec-effect-value", f"{MAKE_REC} --effect transport_delay=abc", "abc"),
    c("mkrec-effect-twice", f"{MAKE_REC} --effect tire_slip --effect tire_slip", "tire_slip"),
    c("mkrec-seed-negative", f"{MAKE_REC} --seed -1", "seed"),
    c("mkrec-model-choice", f"{MAKE_REC} --model warp", "warp"),
    # -- checkpoints (evaluate --checkpoints; train tapm --bm) ---------------------------------
    c("ckpt-dir-missing", "evaluate --policy plm --max-steps 1 --checkpoints nosuch", "nosuch"),
    c("ckpt-no-tapm", EVAL_PLM, ["ck", "tapm"], {"ck": Copy("ck", lambda r: shutil.rmtree(r / "tapm"))}),
    c("ckpt-json-not-json", EVAL_PLM, "model.json", {"ck": Copy("ck", write_bytes("bm/model.json", b"{"))}),
    c("ckpt-json-binary", EVAL_PLM, "model.json", {"ck": Copy("ck", write_bytes("bm/model.json", b"\xff\x00\x81"))}),
    c("ckpt-json-list", EVAL_PLM, "model.json", {"ck": Copy("ck", write_bytes("bm/model.json", b"[]"))}),
    c("ckpt-format-wrong", EVAL_PLM, ["model.json", "format"],
      {"ck": Copy("ck", edit_json("bm/model.json", lambda d: d.update(format="other/9")))}),
    c("ckpt-kinds-swapped", EVAL_PLM, ["model.json", "tapm"],
      {"ck": Copy("ck", lambda r: [shutil.copy(r / "tapm" / n, r / "bm" / n) for n in ("model.pt", "model.json")])}),
    c("ckpt-truncated-weights", EVAL_PLM, "model.pt", {"ck": Copy("ck", truncate("bm/model.pt"))}),
    c("ckpt-empty-weights", EVAL_PLM, "model.pt", {"ck": Copy("ck", write_bytes("bm/model.pt", b""))}),
    c("ckpt-pickle-exploit", EVAL_PLM, "model.pt", {"ck": Copy("ck", malicious_pickle("bm/model.pt"))}),
    c("ckpt-foreign-architecture", EVAL_PLM, "model.pt", {"ck": Copy("ck", foreign_state_dict("bm/model.pt"))}),
    c("ckpt-tapm-weights-as-bm", EVAL_PLM, "model.pt",
      {"ck": Copy("ck", other_model_weights("bm/model.pt", "tapm/model.pt"))}),
    c("ckpt-swapped-same-shape", EVAL_PLM, ["model.pt", "fingerprint"],
      {"ck": Copy("ck", perturbed_weights("bm/model.pt", 0.01))}),
    c("ckpt-nan-weights", EVAL_PLM, "model.pt", {"ck": Copy("ck", perturbed_weights("tapm/model.pt", float("nan")))}),
    c("ckpt-huge-architecture", EVAL_PLM, ["model.json", "image"],
      {"ck": Copy("ck", edit_json("bm/model.json", lambda d: d["architecture"].update(
          image_height_px=3000, image_width_px=3000)))}),
    c("ckpt-architecture-type", EVAL_PLM, ["model.json", "image_height_px"],
      {"ck": Copy("ck", edit_json("bm/model.json", lambda d: d["architecture"].update(image_height_px="66")))}),
    c("ckpt-weights-directory", EVAL_PLM, "model.pt",
      {"ck": Copy("ck", lambda r: ((r / "bm" / "model.pt").unlink(), (r / "bm" / "model.pt").mkdir()))}),
    c("ckpt-tapm-other-bm", EVAL_PLM, ["model.json", "BM"],
      {"ck": Copy("ck", edit_json("tapm/model.json", lambda d: d.update(bm_fingerprint="0" * 64)))}),
    c("ckpt-train-tapm-bm-missing", "train tapm --data ds --bm nosuch --out out --epochs 1 --quiet", "nosuch",
      {"ds": DS}),
    c("ckpt-train-tapm-bm-is-tapm", "train tapm --data ds --bm ck/tapm --out out --epochs 1 --quiet",
      ["model.json", "tapm"], {"ds": DS, "ck": CK}),
    # -- dataset directories (train) ---------------------------------------------------------------
    c("ds-missing", "train bm --data nosuch --out out --epochs 1 --quiet", "nosuch"),
    c("ds-is-file", "train bm --data f --out out --epochs 1 --quiet", "f", {"f": "x"}),
    c("ds-no-manifest", TRAIN, ["ds", "manifest"], {"ds": Copy("ds", lambda r: (r / "manifest.json").unlink())}),
    c("ds-manifest-not-json", TRAIN, "manifest.json", {"ds": Copy("ds", write_bytes("manifest.json", b"{"))}),
    c("ds-manifest-format", TRAIN, ["manifest.json", "format"],
      {"ds": Copy("ds", edit_json("manifest.json", lambda d: d.update(format="x/2")))}),
    c("ds-frames-truncated", TRAIN, "frames.npy", {"ds": Copy("ds", truncate("frames.npy"))}),
    c("ds-frames-pickle", TRAIN, "frames.npy", {"ds": Copy("ds", malicious_npy("frames.npy"))}),
    c("ds-frames-dtype", TRAIN, "frames.npy", {"ds": Copy("ds", frames_as(lambda f: f.astype(np.float64)))}),
    c("ds-frames-fewer-rows", TRAIN, ["ds", "shape"], {"ds": Copy("ds", frames_as(lambda f: f[:-3]))}),
    c("ds-steps-missing", TRAIN, "steps.npz", {"ds": Copy("ds", lambda r: (r / "steps.npz").unlink())}),
    c("ds-steps-nan", TRAIN, ["steps.npz", "steering"], {"ds": Copy("ds", steps_column(
        "steering", lambda s: np.where(np.arange(len(s)) == 3, np.nan, s)))}),
    c("ds-steps-garbage", TRAIN, "steps.npz", {"ds": Copy("ds", write_bytes("steps.npz", b"PK\x03\x04garbage"))}),
    c("ds-empty", TRAIN, "ds", {"ds": Copy("ds", frames_as(lambda f: f[:0]))}),
    c("ds-tapm-frame-size", "train tapm --data ds --bm ck/bm --out out --epochs 1 --quiet --preset paper",
      "preset", {"ds": DS, "ck": CK}),
    # -- every option of every command -----------------------------------------------------------
    c("collect-episodes-zero", "collect --episodes 0 --out out", "--episodes"),
    c("collect-episodes-huge", "collect --episodes 1000000000 --out out", "--episodes"),
    c("collect-episodes-float", "collect --episodes 1.5 --out out", "--episodes"),
    c("collect-seconds-zero", "collect --episode-seconds 0 --out out", "--episode-seconds"),
    c("collect-seconds-nan", "collect --episode-seconds nan --out out", "--episode-seconds"),
    c("collect-seconds-huge", "collect --episode-seconds 1e9 --out out", "--episode-seconds"),
    c("collect-frames-too-many", "collect --episodes 100000 --episode-seconds 100 --out out", ["frames"]),
    c("collect-episode-longer-than-track", "collect --episodes 1 --episode-seconds 3600 --out out",
      ["track 'train'", "shorter than one episode"]),
    c("collect-speed-zero", "collect --speed-mps 0 --out out", "--speed-mps"),
    c("collect-speed-negative", "collect --speed-mps -10 --out out", "--speed-mps"),
    c("collect-speed-huge", "collect --speed-mps 1000 --out out", "--speed-mps"),
    c("collect-offset-off-road", "collect --max-offset-m 50 --out out", "--max-offset-m"),
    c("collect-displaced-fraction", "collect --displaced-fraction 2 --out out", "--displaced-fraction"),
    c("collect-heading", "collect --max-heading-error-deg 90 --out out", "--max-heading-error-deg"),
    c("collect-seed-negative", "collect --seed -1 --out out", "--seed"),
    c("collect-camera", "collect --camera fisheye --out out", "fisheye"),
    c("collect-out-missing", "collect --episodes 1", "--out"),
    c("collect-out-empty", [*COLLECT.split()[:-1], ""], "output path"),
    c("collect-out-dot", [*COLLECT.split()[:-1], "."], "'.'"),
    c("collect-out-foreign-dir", COLLECT, ["out", "thesis.tex"], {"out/thesis.tex": "my thesis"}),
    c("collect-out-file", COLLECT, ["out", "file"], {"out": "a file"}),
    c("collect-out-earlier-no-overwrite", COLLECT, ["out", "--overwrite"], {"out": DS}),
    c("collect-out-under-file", "collect --episodes 1 --episode-seconds 1 --out f/ds", ["f", "not a directory"],
      {"f": "x"}),
    c("train-epochs-zero", f"{TRAIN} --epochs 0", "--epochs", {"ds": DS}),
    c("train-epochs-huge", f"{TRAIN} --epochs 100000", "--epochs", {"ds": DS}),
    c("train-max-samples-one", f"{TRAIN} --max-samples 1", "--max-samples", {"ds": DS}),
    c("train-seed-negative", f"{TRAIN} --seed -1", "--seed", {"ds": DS}),
    c("train-balance-negative", f"{TRAIN} --balance-max-per-bin -1", "--balance-max-per-bin", {"ds": DS}),
    c("train-threads-zero", f"{TRAIN} --threads 0", "--threads", {"ds": DS}),
    c("train-threads-huge", f"{TRAIN} --threads 1000", "--threads", {"ds": DS}),
    c("train-preset-choice", f"{TRAIN} --preset huge", "huge", {"ds": DS}),
    c("train-device-choice", f"{TRAIN} --device tpu", "tpu", {"ds": DS}),
    c("train-out-foreign", TRAIN, ["out", "notes.txt"], {"ds": DS, "out/notes.txt": "mine"}),
    c("train-out-is-data", "train bm --data ds --out ds --epochs 1 --quiet", "ds", {"ds": DS}),
    c("tapm-grid-empty", [*TAPM.split(), "--delta-grid", ""], "--delta-grid", {"ds": DS, "ck": CK}),
    c("tapm-grid-text", f"{TAPM} --delta-grid abc", ["delta", "abc"], {"ds": DS, "ck": CK}),
    c("tapm-grid-zero", f"{TAPM} --delta-grid 0", "delta", {"ds": DS, "ck": CK}),
    c("tapm-grid-decreasing", f"{TAPM} --delta-grid 0.2,0.1", "delta", {"ds": DS, "ck": CK}),
    c("tapm-grid-too-long", f"{TAPM} --delta-grid " + ",".join(f"{0.01 * i:.2f}" for i in range(1, 40)), "delta",
      {"ds": DS, "ck": CK}),
    c("tapm-preset-mismatch", f"{TAPM} --preset paper", "preset", {"ds": DS, "ck": CK}),
    c("eval-max-steps-zero", "evaluate --policy expert --max-steps 0", "--max-steps"),
    c("eval-seed-negative", "evaluate --policy expert --seed -1", "--seed"),
    c("eval-seed-huge", "evaluate --policy expert --seed 99999999999", "--seed"),
    c("eval-policy-choice", "evaluate --policy magic", "magic"),
    c("eval-json-foreign", EVAL, ["out.json", "bytes"], {"out.json": "{\"mine\": 1}"}),
    c("eval-json-is-dir", EVAL, ["out.json", "directory"], {"out.json/x": "x"}),
    c("eval-out-foreign", "evaluate --policy expert --max-steps 1 --out res", ["res", "data.csv"],
      {"res/data.csv": "a,b"}),
    c("eval-out-is-file", "evaluate --policy expert --max-steps 1 --out res", "res", {"res": "x"}),
    c("eval-json-same-as-out", "evaluate --policy expert --max-steps 1 --out res --json res", "res"),
    c("eval-json-home", "evaluate --policy expert --max-steps 1 --json " + str(Path.home()), "home"),
    c("eval-json-root", "evaluate --policy expert --max-steps 1 --json /", "'/'"),
    c("eval-json-symlink", EVAL, ["out.json", "link"], {"target.json": "{}", "out.json": Make(
        lambda p: p.symlink_to("target.json"))}),
    c("reproduce-settings-bad", "reproduce --settings const:abc --max-steps 1 --out rep --no-progress", "const:abc"),
    c("reproduce-sweep-step-zero", "reproduce --sweep --sweep-step 0 --out rep", "--sweep-step"),
    c("reproduce-sweep-max-big", "reproduce --sweep --sweep-max 2 --out rep", "--sweep-max"),
    c("reproduce-max-steps-zero", "reproduce --max-steps 0 --out rep", "--max-steps"),
    c("reproduce-generalise-missing", "reproduce --generalise nosuch.json --max-steps 1 --out rep --no-progress",
      "nosuch.json"),
    c("reproduce-track-missing", "reproduce --track nosuch.json --max-steps 1 --out rep --no-progress", "nosuch.json"),
    c("reproduce-out-foreign", "reproduce --max-steps 1 --out rep --no-progress", ["rep", "paper.md"],
      {"rep/paper.md": "mine"}),
    c("reproduce-checkpoints-missing", "reproduce --max-steps 1 --out rep --no-progress --checkpoints nosuch",
      "nosuch"),
    c("demo-out-not-png", "demo zigzag --policy expert --out z.jpg", ["z.jpg", "PNG"]),
    c("demo-out-foreign", "demo zigzag --policy expert --out z.png", ["z.png", "bytes"],
      {"z.png": b"\x89PNG\r\n\x1a\nnot ours"}),
    c("demo-policy-choice", "demo zigzag --policy magic", "magic"),
    c("demo-track-missing", "demo zigzag --policy expert --out z.png --track nosuch.json", "nosuch.json"),
    c("estimate-seeds-zero", "estimate table3 --seeds 0", "--seeds"),
    c("estimate-scenario-unknown", "estimate table3 --scenarios 5 --json t.json", ["5", "scenario"]),
    c("estimate-scenario-text", "estimate table3 --scenarios a,b --json t.json", ["a", "scenario"]),
    c("estimate-json-foreign", "estimate table3 --seeds 1 --json t.json", ["t.json", "bytes"], {"t.json": "{}"}),
    c("bench-env-steps", "bench env --steps 5", "--steps"),
    c("bench-env-repeats-zero", "bench env --steps 50 --repeats 0", "--repeats"),
    c("bench-env-json-foreign", "bench env --steps 50 --repeats 1 --json b.json", ["b.json", "bytes"],
      {"b.json": "{}"}),
    c("bench-models-frames", "bench models --frames 0", "--frames"),
    c("bench-models-threads", "bench models --threads 0", "--threads"),
    c("bench-models-preset", "bench models --preset huge", "huge"),
    c("bench-models-device", "bench models --device tpu", "tpu"),
    c("bench-models-weights", "bench models --weights trained", "trained"),
    c("bench-metrics-points", "bench metrics --points 0", "--points"),
    c("bench-metrics-repeat", "bench metrics --repeat 0", "--repeat"),
    c("bench-estimation-delay", "bench estimation --delay 0", "--delay"),
    c("bench-estimation-repeats", "bench estimation --repeats 0", "--repeats"),
    c("lessons-grade-missing", f"lessons grade nosuch --csv s.csv --solutions {REPO_ROOT / 'solutions'}", "nosuch"),
    c("lessons-grade-csv-foreign", "lessons grade subs --csv s.csv", ["s.csv", "bytes"],
      {"subs/x/lesson.ipynb": "{}", "s.csv": "name,grade\n"}),
    c("lessons-build-solutions-missing", "lessons build --solutions nosuch --lessons L --check", "nosuch"),
    c("lessons-figures-out-file", "lessons figures --out f", ["f", "file"], {"f": "x"}),
    c("lessons-timing-missing", "bench lessons --solutions nosuch", "nosuch"),
    c("unknown-command", "frobnicate", "frobnicate"),
    c("unknown-option", "collect --out out --frobnicate", "--frobnicate"),
    # -- bounded work: every structured input read in linear time within explicit limits -------------
    c("track-escaped-quotes-unterminated", f"{EVAL} --track t.json", ["t.json", "not valid JSON"],
      {"t.json": '{"name": "' + '\\"' * 40_000}, timeout_s=10),
    c("track-escaped-quotes-name", f"{EVAL} --track t.json", ["t.json", "'name'"],
      {"t.json": '{"name": "' + '\\"' * 40_000 + '", "segments": [{"type": "straight", "length_m": 50}]}'},
      timeout_s=10),
    c("track-5000-digit-integer", f"{EVAL} --track t.json", ["t.json", "'lanes'", "5,000 digits", "at most 20"],
      {"t.json": '{"name": "t", "lanes": ' + "1" * 5000 + ', "segments": []}'}, timeout_s=10),
    c("track-long-integer-in-segment", f"{EVAL} --track t.json", ["t.json", "segments[0].length_m", "digits"],
      {"t.json": '{"name": "t", "segments": [{"type": "straight", "length_m": ' + "9" * 300 + '}]}'}),
    c("track-duplicate-key", f"{EVAL} --track t.json", ["t.json", "'name'", "more than once"],
      {"t.json": '{"name": "t", "name": "u", "segments": [{"type": "straight", "length_m": 50}]}'}),
    c("track-duplicate-key-in-segment", f"{EVAL} --track t.json", ["t.json", "segments[0]", "'length_m'"],
      {"t.json": '{"name": "t", "segments": [{"type": "straight", "length_m": 50, "length_m": 5000}]}'}),
    c("track-too-many-values", f"{EVAL} --track t.json", ["t.json", "20,000 values", "node limit"],
      {"t.json": track_with(closed=[0] * 30_000)}, timeout_s=10),
    c("track-nested-200k", f"{EVAL} --track t.json", ["t.json", "nested 200000 deep", "at most 16"],
      {"t.json": "[" * 200_000 + "]" * 200_000}, timeout_s=10),
    c("grid-json-nested-200k", f"{SWEEP} --grid g.json", ["g.json", "nested 200000 deep"],
      {"g.json": "[" * 200_000 + "]" * 200_000}, timeout_s=10),
    c("grid-yaml-alias-bomb", f"{SWEEP} --grid g.yaml", ["g.yaml", "aliases are counted after expansion"],
      {"g.yaml": ALIAS_BOMB}, timeout_s=10),
    c("grid-yaml-nested-deep", f"{SWEEP} --grid g.yaml", ["g.yaml", "nested more than 16 deep"],
      {"g.yaml": "latencies: " + "[" * 20_000 + "]" * 20_000}, timeout_s=10),
    c("grid-yaml-5000-digit-seeds", f"{SWEEP} --grid g.yaml", ["g.yaml", "'seeds'", "5,000 digits"],
      {"g.yaml": "seeds: " + "7" * 5000 + "\n"}, timeout_s=10),
    c("grid-yaml-duplicate-key", f"{SWEEP} --grid g.yaml", ["g.yaml", "'seeds'", "more than once"],
      {"g.yaml": "seeds: 1\nseeds: 2\n"}),
    c("grid-json-duplicate-key", f"{SWEEP} --grid g.json", ["g.json", "'seeds'", "more than once"],
      {"g.json": '{"seeds": 1, "policies": ["expert"], "seeds": 2}'}),
    c("grid-yaml-python-object", f"{SWEEP} --grid g.yaml", ["g.yaml", "not valid YAML"],
      {"g.yaml": f"latencies: !!python/object/apply:os.system ['touch {MARKER}']\n"}),
    c("grid-too-large", f"{SWEEP} --grid g.yaml", ["g.yaml", "1,048,576"], {"g.yaml": Make(sparse_file(2 << 20))}),
    c("grid-non-ascii-latency", f"{SWEEP} --grid g.yaml", ["const:\u0660.\u0661"],
      {"g.yaml": "latencies: ['const:\u0660.\u0661']\n"}),
    c("grid-non-ascii-seeds", f"{SWEEP} --grid g.yaml", ["seeds", "non-ASCII digit"], {"g.yaml": "seeds: '\u0663'\n"}),
    c("ckpt-json-nested-200k", EVAL_PLM, ["model.json", "nested 200000 deep"],
      {"ck": Copy("ck", write_bytes("bm/model.json", b"[" * 200_000 + b"]" * 200_000))}, timeout_s=20),
    c("ckpt-json-duplicate-key", EVAL_PLM, ["model.json", "'kind'", "more than once"],
      {"ck": Copy("ck", lambda r: (r / "bm" / "model.json").write_text(
          (r / "bm" / "model.json").read_text().replace('"kind":', '"kind": "tapm", "kind":', 1)))}),
    c("ckpt-tapm-grid-edited", EVAL_PLM, ["tapm/model.json", "changed after it was saved"],
      {"ck": Copy("ck", edit_json("tapm/model.json", lambda d: d["architecture"].update(
          delta_grid_s=[0.1, 0.2, 0.25, 0.3, 0.4])))}),
    c("ckpt-tapm-recorded-grid-edited", EVAL_PLM, ["tapm/model.json", "changed after it was saved"],
      {"ck": Copy("ck", edit_json("tapm/model.json", lambda d: d.update(delta_grid_s=[0.1, 0.2, 0.25, 0.3, 0.4])))}),
    c("ckpt-bm-preset-edited", EVAL_PLM, ["bm/model.json", "changed after it was saved"],
      {"ck": Copy("ck", edit_json("bm/model.json", lambda d: d.update(preset="paper")))}),
    c("ckpt-bm-lead-added", EVAL_PLM, ["bm/model.json", "changed after it was saved"],
      {"ck": Copy("ck", edit_json("bm/model.json", lambda d: d.update(label_lead_s=0.25)))}),
    c("ckpt-seal-removed", EVAL_PLM, ["model.json", "description_sha256"],
      {"ck": Copy("ck", edit_json("tapm/model.json", lambda d: d.pop("description_sha256") and None))}),
    c("ckpt-train-tapm-bm-edited", "train tapm --data ds --bm ck/bm --out out --epochs 1 --quiet",
      ["bm/model.json", "changed after it was saved"],
      {"ds": DS, "ck": Copy("ck", edit_json("bm/model.json", lambda d: d.update(preset="paper")))}),
    c("ds-manifest-nested-200k", TRAIN, ["manifest.json", "nested 200000 deep"],
      {"ds": Copy("ds", write_bytes("manifest.json", b"[" * 200_000 + b"]" * 200_000))}, timeout_s=20),
    c("ds-manifest-duplicate-key", TRAIN, ["manifest.json", "'format'", "more than once"],
      {"ds": Copy("ds", lambda r: (r / "manifest.json").write_text(
          (r / "manifest.json").read_text().replace('"format":', '"format": "x", "format":', 1)))}),
    c("ds-marker-duplicate-key", "collect --track test --episodes 1 --episode-seconds 1 --out ds --overwrite",
      ["ds", "marker cannot be trusted", "'kind'", "more than once"],
      {"ds": Copy("ds", lambda r: (r / ".plm-highway-output.json").write_text(
          (r / ".plm-highway-output.json").read_text().replace('"kind":', '"kind":"x","kind":', 1)))}),
    c("ds-steering-label-40", TRAIN, ["steps.npz", "'steering'", "40", "row 3", "[-1, 1]"],
      {"ds": Copy("ds", edit_steps("steering", 3, 40.0))}),
    c("ds-manifest-speed-edited", TRAIN, ["manifest.json", "'speed_mps' = 30", "median"],
      {"ds": Copy("ds", edit_json("manifest.json", lambda d: d.update(speed_mps=30)))}),
    c("ds-manifest-camera-size-edited", TRAIN, ["manifest.json", "160x160", "frames.npy"],
      {"ds": Copy("ds", edit_json("manifest.json", lambda d: d["camera"].update(height_px=160, width_px=160)))}),
    c("ds-manifest-pitch-out-of-range", TRAIN, ["manifest.json", "'camera.pitch_deg' = 600"],
      {"ds": Copy("ds", edit_json("manifest.json", lambda d: d["camera"].update(pitch_deg=600)))}),
    c("ds-manifest-pitch-edited-in-range", TRAIN, ["manifest.json", "edited after plm-highway wrote it"],
      {"ds": Copy("ds", edit_json("manifest.json", lambda d: d["camera"].update(pitch_deg=d["camera"]["pitch_deg"]
                                                                                   + 3.0)))}),
    c("ds-manifest-without-digest", TRAIN, ["manifest.json", "no content digest"],
      {"ds": Copy("ds", edit_json("manifest.json", lambda d: d.__delitem__("content_sha256")))}),
    c("trace-million-columns", f"{EVAL} --latency trace:trace.csv", ["trace.csv", "row 2", "64 columns"],
      trace_rows("t,latency_s\n" + "0" + "," * 1_000_000 + "\n"), timeout_s=10),
    c("sidecar-nested-30k", DIAG, ["r.json", "nested"],
      {"rec": Copy("rec", write_bytes("r.json", b"[" * 30_000 + b"]" * 30_000))}, timeout_s=20),
    # -- numbers with digits other than 0-9, nonsense option values -----------------------------------
    c("non-ascii-max-steps", "evaluate --policy expert --max-steps \u0663", ["--max-steps", "non-ASCII digit"]),
    c("non-ascii-seed", "evaluate --policy expert --max-steps 1 --seed \u0663", ["--seed", "non-ASCII digit"]),
    c("non-ascii-fullwidth-episodes", "collect --episodes \uff13 --out out", ["--episodes", "non-ASCII digit"]),
    c("non-ascii-epochs", f"{TRAIN} --epochs \u0967", ["--epochs", "non-ASCII digit"], {"ds": DS}),
    c("non-ascii-latency", f"{EVAL} --latency const:\u0660.\u0661", "const:\u0660.\u0661"),
    c("non-ascii-seeds-list", "evaluate --policy expert --max-steps 1 --seeds 0,\u0663", ["--seeds", "non-ASCII"]),
    c("non-ascii-delta-grid", f"{TAPM} --delta-grid 0.1,\u0660.\u0662", ["--delta-grid", "non-ASCII"],
      {"ds": DS, "ck": CK}),
    c("non-ascii-block-s", f"{DIAG} --block-s \u0665", ["--block-s", "non-ASCII"], {"rec": REC}),
    # -- one strict number parser: no '_' separators, integers where integers are meant, text names typed ------
    c("underscore-max-steps", "sweep --out sw --workers 0 --policy expert --max-steps 1_0", ["--max-steps", "'_'"]),
    c("underscore-seeds", "evaluate --policy expert --max-steps 1 --seeds 0,1_0", ["--seeds", "1_0"]),
    c("grid-seed-as-text", f"{SWEEP} --grid g.yaml", ["seeds[0]", "'1'", "integer"], {"g.yaml": "seeds: ['1']\n"}),
    c("grid-condition-named-by-a-number", f"{SWEEP} --grid g.yaml", ["conditions name 1", "quotes"],
      {"g.yaml": "conditions:\n  1: {}\n  '1': {}\n"}),
    c("grid-track-named-by-a-number", f"{SWEEP} --grid g.yaml", ["tracks[0]", "int"], {"g.yaml": "tracks: [7]\n"}),
    c("rec-arabic-indic-digit", DIAG, ["r.csv", "speed", "line 6", "non-ASCII digit"],
      {"rec": Copy("rec", recording_rows(set_cell("speed", 5, "\u0661\u0665")))}),
    c("rec-underscore-separator", DIAG, ["r.csv", "speed", "line 6", "'_'"],
      {"rec": Copy("rec", recording_rows(set_cell("speed", 5, "1_5")))}),
    c("trace-underscore-separator", f"{EVAL} --latency trace:trace.csv", ["trace.csv", "row 2", "'0_1'",
      "not a plain decimal"], trace_rows("t,latency_s\n0,0_1\n1,0.1\n")),
    c("trace-arabic-indic-digit", f"{EVAL} --latency trace:trace.csv", ["trace.csv", "row 2", "not a plain decimal"],
      trace_rows("t,latency_s\n0,\u0660.1\n1,0.1\n")),
    c("non-ascii-sweep-seeds", f"{SWEEP} --seeds \u0663", ["seeds", "non-ASCII"]),
    c("diag-block-nanoseconds", f"{DIAG} --block-s 1e-9", "--block-s", {"rec": REC}),
    c("diag-block-tenth-second", f"{DIAG} --block-s 0.1", "--block-s", {"rec": REC}),
    # -- errors that name the culprit; outputs that name a directory -----------------------------------
    c("settings-trace-path-with-comma", "reproduce --settings trace:my,trace.csv --max-steps 1 --out rep --no-progress",
      "my,trace.csv"),
    c("eval-json-trailing-slash", f"{EVAL[:-len('out.json')]}res/", ["res/", "directory"]),
    c("estimate-json-trailing-slash", "estimate table3 --seeds 1 --json t/", ["t/", "directory"]),
    c("lessons-grade-notebook-nested-200k", f"lessons grade subs --csv s.csv --solutions {REPO_ROOT / 'solutions'}",
      ["subs/ann/01_latency_zigzag.ipynb", "nested 200000 deep"],
      {"subs/ann/01_latency_zigzag.ipynb": "[" * 200_000 + "]" * 200_000}, timeout_s=120),
    c("train-tapm-over-its-own-bm", "train tapm --data ds --bm ck/bm --out ck/bm --epochs 1 --quiet --overwrite",
      ["ck/bm", "input of this run"], {"ds": DS, "ck": CK}),
    c("generalise-two-tracks-one-name", "reproduce --generalise a/t.json b/t.json --max-steps 1 --out rep --no-progress",
      ["a/t.json", "b/t.json", "both named"], {"a/t.json": TRACK, "b/t.json": TRACK}),
]


def _params():
    for case in CASES:
        marks = [pytest.mark.timeout(case.timeout_s)]
        if case.owner:
            marks.append(pytest.mark.xfail(strict=True, reason=f"owner {case.owner}: {case.why}"))
        yield pytest.param(case, id=case.id, marks=marks)


def _materialise(case: Case, root: Path, fixtures: dict[str, Path]) -> None:
    for relative, content in case.files.items():
        path = root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, Copy):
            shutil.copytree(fixtures[content.fixture], path)
            if content.then is not None:
                content.then(path)
        elif isinstance(content, Make):
            content.make(path)
        elif isinstance(content, bytes):
            path.write_bytes(content)
        elif isinstance(content, str):
            path.write_text(content)
        else:
            path.write_text(json.dumps(content))


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every path under ``root`` (hidden ones too) with its bytes; directories and links as None."""
    state = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            path = Path(dirpath) / name
            rel = str(path.relative_to(root))
            if path.is_symlink() or path.is_dir():
                state[rel] = None
            elif path.stat().st_size > 64 << 20:
                state[rel] = b"size:%d" % path.stat().st_size
            else:
                state[rel] = path.read_bytes()
    return state


@pytest.mark.parametrize("case", list(_params()))
def test_bad_input_is_refused_cleanly(case: Case, fixtures, tmp_path, monkeypatch, capsys):
    workdir = tmp_path / "work"
    workdir.mkdir()
    _materialise(case, workdir, fixtures)
    before = snapshot(tmp_path)
    monkeypatch.chdir(workdir)
    code = main(list(case.argv))
    captured = capsys.readouterr()
    stderr = captured.err
    assert "Traceback" not in stderr and "Traceback" not in captured.out, stderr[-2000:]
    assert code == 2, f"exit {code}; stderr: {stderr[-2000:]}"
    missing = [name for name in case.names if name not in stderr]
    assert not missing, f"message does not name {missing}: {stderr[-2000:]}"
    assert not (workdir / MARKER).exists(), "an input pickle was executed"
    assert snapshot(tmp_path) == before, "the refused command left something behind or changed an input"


def test_battery_is_large_and_distinct():
    ids = [case.id for case in CASES]
    assert len(ids) == len(set(ids))
    assert len({case.argv + tuple(sorted(map(str, case.files))) for case in CASES}) >= 80
    assert len(CASES) >= 80


@pytest.mark.timeout(900)
def test_the_readme_quotes_the_battery_sizes():
    from battery_counts import battery_counts, readme_counts

    counted = battery_counts()
    assert all(counted.values()), counted  # the counting itself works
    assert readme_counts() == counted, "docs/reliability.md's 'Battery sizes' line disagrees with the test files: update it"
