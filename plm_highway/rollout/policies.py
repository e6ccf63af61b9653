"""Policies by name, for the command line: ``expert``, ``bm`` (Base Model), ``plm`` (PLM-Net), ``ekf``
(the model-based alternative: :class:`plm_highway.lane_ekf.policy.EkfLaneKeepingPolicy`, the
delay-compensated lane EKF and a controller on its state; no checkpoints), and the frozen BM with a plug-in
mitigation (:data:`MITIGATED_POLICIES`, :mod:`plm_highway.mitigation`): ``bm-warp``, ``bm-smith``.

Model policies load a checkpoint pair (Base Model + TAPM). ``--checkpoints DIR`` accepts the two
layouts the project writes: ``DIR/bm/`` + ``DIR/tapm/`` (each ``model.pt`` + ``model.json``, as
``plm-highway train bm|tapm --out`` writes them) or ``DIR/bm_default.*`` + ``DIR/tapm_default.*``
(how they are shipped in ``plm_highway/checkpoints``). Without a directory the shipped pair is used.
PLM-Net is always the Base Model of the same pair plus its TAPM, so the mitigated run differs
from the baseline run only by the TAPM.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import torch

from plm_highway.camera.pinhole import CameraConfig
from plm_highway.errors import BadInput
from plm_highway.expert import ExpertPolicy
from plm_highway.io.digests import file_sha256
from plm_highway.lane_ekf.lateral_control import LoopTiming, single_track_equivalent
from plm_highway.lane_ekf.policy import ekf_policy
from plm_highway.mitigation import make_mitigation
from plm_highway.models import checkpoints, inference
from plm_highway.models.base_model import PRESETS
from plm_highway.models.checkpoints import checkpoint_paths
from plm_highway.models.device import resolve_device
from plm_highway.models.shipped import shipped_checkpoint_dir, shipped_checkpoint_paths
from plm_highway.rollout.closed_loop import Policy
from plm_highway.rollout.conditions import CONDITIONS, Conditions
from plm_highway.vehicle.models import checked_params, vehicle_model


@dataclass(frozen=True)
class PolicyKind:
    """What a policy name means to every command that drives (:data:`POLICIES`): adding a policy is one entry."""

    label: str  # how reports and printed summaries name it
    reference: str  # the policy of the runs it is compared with: its reference (no latency) and its baseline
    mitigates: bool  # driven as the "mitigated" run beside that baseline (evaluate, sweeps' reductions)
    model: str | None = None  # the checkpoint model it runs ("bm": the Base Model; "plm": BM + TAPM); None: none
    mitigation: str | None = None  # a plug-in mitigation (plm_highway.mitigation) on the frozen BM, by its name

    @property
    def reads_checkpoints(self) -> bool:
        return self.model is not None


# The one table of policies (a literal dict: the command line reads its names without importing this module).
# The EKF lane keeper is compared with itself in `evaluate` (fusing late frames as if current, then re-stamping
# them); in a sweep its steering is compared with the BM's, as every model policy's.
POLICIES = {
    "expert": PolicyKind("expert driver", reference="expert", mitigates=False),
    "bm": PolicyKind("Base Model", reference="bm", mitigates=False, model="bm"),
    "plm": PolicyKind("PLM-Net", reference="bm", mitigates=True, model="plm"),
    "ekf": PolicyKind("EKF lane keeper", reference="bm", mitigates=False),
    "bm-warp": PolicyKind("BM with image warping", reference="bm", mitigates=True, model="bm", mitigation="warp"),
    "bm-smith": PolicyKind("BM with a Smith predictor", reference="bm", mitigates=True, model="bm",
                           mitigation="smith"),
}
POLICY_NAMES = tuple(POLICIES)
# Policies that are the frozen BM with a plug-in mitigation (plm_highway.mitigation), by the mitigation's name.
MITIGATED_POLICIES = {name: kind.mitigation for name, kind in POLICIES.items() if kind.mitigation is not None}
# Policies evaluated as the "mitigated" run beside the BM.
MITIGATING_POLICIES = tuple(name for name, kind in POLICIES.items() if kind.mitigates)
# Policies whose runs read a checkpoint pair (loaded once per process and shared by the runs).
MODEL_POLICIES = tuple(name for name, kind in POLICIES.items() if kind.reads_checkpoints)


def policy_kind(name: str) -> PolicyKind:
    """The registry's entry for ``name``, or a ValueError naming the known ones."""
    kind = POLICIES.get(name) if isinstance(name, str) else None
    if kind is None:
        raise ValueError(f"--policy {name!r}: expected one of {list(POLICY_NAMES)}")
    return kind
# What PLM-Net is told -> the info key it reads; "estimated" is the latency estimated from the stream
# (plm_highway.lane_ekf.latency_stream, added to info by the run's LatencyEstimateWrapper).
LATENCY_SOURCES = {"measured": "observation_age_s", "requested": "latency_s", "estimated": "latency_estimate_s"}
SHIPPED_PRESET = "default"


class VisionPolicy:
    """Adapts a model policy ``(frame, speed_mps, latency_s) -> steering`` to ``(frame, info)``.

    The latency it is told is the *measured* age of the observation, as PLM-Net is deployed
    (``latency_source="measured"``), or the *requested* latency ``info["latency_s"]``, as the original
    code told it while its FIFO served other ages (``"requested"``), plus ``latency_bias_s`` (a wrong
    latency estimate; clipped at 0).
    """

    def __init__(self, model_policy, latency_bias_s: float = 0.0, latency_source: str = "measured", mitigation=None):
        if latency_source not in LATENCY_SOURCES:
            raise ValueError(f"latency_source {latency_source!r}: expected one of {list(LATENCY_SOURCES)}")
        self.model_policy = model_policy
        self.latency_bias_s = latency_bias_s
        self.latency_source = latency_source
        self.info_key = LATENCY_SOURCES[latency_source]
        # A plug-in mitigation of this run (plm_highway.mitigation): what the model sees and what is issued.
        self.mitigation = mitigation

    def reset(self) -> None:
        self.model_policy.reset()
        if self.mitigation is not None:
            self.mitigation.reset()

    def latency_s(self, info) -> float:
        """The frame's age as this policy is told it."""
        return max(0.0, info[self.info_key] + self.latency_bias_s)

    def model_input(self, frame, info):
        """The frame the model is given (the mitigation's, if any)."""
        if self.mitigation is None:
            return frame
        return self.mitigation.model_input(frame, info, self.latency_s(info))

    def output(self, steering: float, info) -> float:
        """The steering issued for the model's ``steering``."""
        return steering if self.mitigation is None else float(self.mitigation.output(steering, info))

    @property
    def clamped_count(self) -> int:
        """Steps whose latency was above the TAPM grid (PLM-Net used its last head)."""
        return int(getattr(self.model_policy, "clamped_latency_count", 0))

    def __call__(self, frame, info) -> float:
        """The steering for one frame outside the closed loop (which steers its runs in batches through
        :meth:`model_input`, :meth:`latency_s` and :meth:`output`)."""
        steering = float(self.model_policy(self.model_input(frame, info), info["speed_mps"], self.latency_s(info)))
        return self.output(steering, info)


@contextlib.contextmanager
def single_threaded_inference() -> Iterator[None]:
    """Run torch on one thread inside the block (restored after).

    Closed-loop driving evaluates one frame at a time: a second thread gains nothing on so small a
    batch, and on a busy machine the thread hand-offs made each step 3-30x slower in our measurements.
    """
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def checkpoint_pair(checkpoint_dir=None, preset: str = SHIPPED_PRESET) -> tuple[Path, Path]:
    """(BM, TAPM) checkpoint paths in ``checkpoint_dir`` (see the module docstring), or the shipped pair.

    Raises FileNotFoundError naming what is missing and how to get it.
    """
    if checkpoint_dir is None:
        bm_path, tapm_path = shipped_checkpoint_paths(preset)
        missing = [f.name for w in (bm_path, tapm_path) for f in (w, w.with_suffix(".json")) if not f.is_file()]
        if missing:
            raise FileNotFoundError(
                f"no shipped checkpoints in {shipped_checkpoint_dir()} (missing {', '.join(missing)}); "
                f"pass --checkpoints DIR with bm/ and tapm/ from 'plm-highway train bm|tapm --out'"
            )
        return bm_path, tapm_path
    directory = Path(checkpoint_dir)
    if not directory.is_dir():
        raise FileNotFoundError(f"--checkpoints {str(directory)!r}: no such directory")
    layouts = ((directory / "bm", directory / "tapm"),
               (directory / f"bm_{preset}.pt", directory / f"tapm_{preset}.pt"))
    for bm_path, tapm_path in layouts:
        if (bm_path / "model.pt").is_file() or (bm_path.suffix == ".pt" and bm_path.is_file()):
            return bm_path, tapm_path
    raise FileNotFoundError(
        f"--checkpoints {str(directory)!r}: expected bm/model.pt and tapm/model.pt (from 'plm-highway train') "
        f"or bm_{preset}.pt and tapm_{preset}.pt (the shipped layout)"
    )


def checkpoint_pair_sha256(checkpoint_dir=None, preset: str = SHIPPED_PRESET) -> dict[str, str]:
    """What the pair of :func:`checkpoint_pair` holds, by content: ``{"bm.pt": sha256, "bm.json": ..., "tapm.pt": ...,
    "tapm.json": ...}``; a model retrained into the same directory gives other digests."""
    digests = {}
    for role, path in zip(("bm", "tapm"), checkpoint_pair(checkpoint_dir, preset)):
        weights, description = checkpoint_paths(path)
        digests[f"{role}.pt"] = file_sha256(weights, f"{role} checkpoint")
        digests[f"{role}.json"] = file_sha256(description, f"{role} checkpoint description")
    return digests


def ekf_plant(conditions) -> dict:
    """What the EKF lane keeper must know of ``conditions`` (a :class:`~plm_highway.rollout.conditions.Conditions`):
    the camera, the steering range, the loop period, the actuator's lag and the processing delay (its LQR's
    plant), and the car of the conditions' vehicle model as a linear single-track car (its estimator's model)."""
    return run_plant(conditions.camera, conditions.env_config())


def run_plant(camera: dict | None, env_config: dict | None) -> dict:
    """:func:`ekf_plant` from what a run holds (a :class:`~plm_highway.rollout.closed_loop.RunCell`'s ``camera`` and
    ``env_config``; the env's defaults for what they leave out)."""
    config = env_config or {}
    params = checked_params(vehicle_model(config.get("vehicle_model", "kinematic")), config.get("vehicle_params") or {})
    return {"camera": CameraConfig.from_dict(camera or {}), "max_steering_rad": config.get("max_steering_rad", 0.2),
            "timing": LoopTiming(1.0 / config.get("policy_frequency", 20), config.get("steering_time_constant_s", 0.0),
                                 config.get("processing_delay_steps", 0)),
            "vehicle": single_track_equivalent(params)}


def make_policy(name: str, checkpoint_dir=None, latency_bias_s: float = 0.0, latency_source: str = "measured",
                seed: int = 0, preset: str = SHIPPED_PRESET, conditions=None, compensate_delay: bool = True,
                device="cpu"):
    """The policy named ``name``; model policies load the shipped ``preset`` checkpoints unless given a dir
    and run batch-invariantly (:mod:`plm_highway.models.batch_invariant`).

    ``seed`` seeds the EKF policy's own sensor noise (the others have none); ``conditions`` (default: the ideal
    ones) set its plant (:func:`ekf_plant`) and ``compensate_delay`` whether it re-stamps late frames.
    ``device`` (``cpu``, ``cuda``, ``auto`` or a torch.device; see :func:`plm_highway.models.device.resolve_device`)
    is where a model policy's model and input tensors live; its steering comes back as Python floats whatever the
    device. The batch-invariant kernels, and with them the guarantee that batched and one-env runs agree bit for
    bit, are the CPU's. The expert and the EKF run on the host and ignore it.
    """
    kind = policy_kind(name)
    if kind.model is None:
        return policy_for_run(name, None, latency_bias_s=latency_bias_s, latency_source=latency_source,
                              seed=seed, compensate_delay=compensate_delay,
                              plant={} if conditions is None else ekf_plant(conditions))

    device = resolve_device(device)  # refused (cuda without CUDA) before any checkpoint is read
    bm_path, tapm_path = checkpoint_pair(checkpoint_dir, preset)
    # Batch-invariant kernels: a run's result does not depend on which runs shared its batch (or on
    # running alone), so batched, pooled and one-env runs of one seed give the same numbers.
    if kind.model == "bm":
        model = checkpoints.load_base_model(bm_path, device)
        check_preset(model.config, bm_path, checkpoint_dir, preset)
        model_policy = inference.BaseModelPolicy(model, batch_invariant=True)
    else:
        net = checkpoints.load_plm_net(bm_path, tapm_path, device)
        check_preset(net.bm.config, bm_path, checkpoint_dir, preset)
        model_policy = inference.PLMNetPolicy(net, batch_invariant=True)
    if kind.mitigation is None:
        if kind.model == "bm":  # the Base Model reads no latency
            return VisionPolicy(model_policy)
        return policy_for_run(name, model_policy, latency_bias_s=latency_bias_s, latency_source=latency_source)
    # without conditions: those the preset's checkpoints are meant for (their camera is the one they see)
    conditions = conditions or next(c for c in CONDITIONS.values() if c.checkpoint_preset == preset)
    return policy_for_run(name, model_policy, latency_bias_s=latency_bias_s, latency_source=latency_source,
                          seed=seed, camera=conditions.camera, env_config=conditions.env_config())


def policy_for_run(name: str, model_policy=None, *, latency_bias_s: float = 0.0, latency_source: str = "measured",
                   seed: int = 0, camera=None, env_config=None, compensate_delay: bool = True,
                   plant: dict | None = None) -> Policy:
    """The policy object of one run of ``name``: a model policy's ``model_policy`` (loaded once, shared by runs)
    told this run's latency, with the run's own plug-in mitigation; the expert; or an EKF keeper with the run's own
    sensor noise (``seed``) and plant (``plant``: :func:`ekf_plant`'s keywords; None: the run's, from ``camera``
    and ``env_config``)."""
    kind = policy_kind(name)
    if name == "expert":
        return ExpertPolicy()
    if name == "ekf":
        plant = run_plant(camera, env_config) if plant is None else plant
        return ekf_policy(compensate_delay=compensate_delay, latency_bias_s=latency_bias_s, seed=seed,
                          latency_source=latency_source, **plant)
    mitigation = None
    if kind.mitigation is not None:  # a per-run object: the run's camera, its own sensor noise
        mitigation = make_mitigation(kind.mitigation, camera, seed, model_policy, env_config)
    return VisionPolicy(model_policy, latency_bias_s, latency_source, mitigation)


def check_preset(config, bm_path, checkpoint_dir, preset: str) -> None:
    """Refuse a checkpoint pair whose input size is not the one ``preset`` (that of the run's conditions) renders,
    naming both presets, rather than failing at the first frame with the frame's shape."""
    wanted = PRESETS.get(preset)
    if wanted is None:
        return
    have = (config.image_size_px, config.input_channels)
    if have == (wanted.image_size_px, wanted.input_channels):
        return
    theirs = next((name for name, c in PRESETS.items() if (c.image_size_px, c.input_channels) == have), None)
    where = "the shipped checkpoints" if checkpoint_dir is None else f"the checkpoints at {str(checkpoint_dir)!r}"

    def size(c) -> str:
        return f"{c.image_size_px[0]}x{c.image_size_px[1]}, {c.input_channels} channel(s)"

    are = f"preset {theirs!r} ({size(config)})" if theirs else f"an input of {size(config)}"
    raise BadInput(f"{where} are {are} but these conditions need preset {preset!r} ({size(wanted)}); pass "
                   f"--checkpoints with a {preset!r} pair (plm-highway train bm|tapm --preset {preset}) or choose "
                   f"conditions for {theirs or 'that'} input ({Path(bm_path)})")


def biased(policy: Policy, latency_bias_s: float) -> Policy:
    """``policy``, told its latency + ``latency_bias_s`` if that is not 0 (a model policy: a wrong latency estimate)."""
    if not latency_bias_s:
        return policy
    if not isinstance(policy, VisionPolicy):
        raise ValueError(f"a latency bias of {latency_bias_s} s needs a model policy, not a {type(policy).__name__}")
    return VisionPolicy(policy.model_policy, latency_bias_s, policy.latency_source)


def make_policies(checkpoints, conditions: Conditions, device="cpu") -> dict[str, Policy]:
    """``{"bm": Base Model, "plm": PLM-Net}`` from one checkpoint pair on ``device``, PLM-Net told the latency
    these conditions say."""
    return {"bm": make_policy("bm", checkpoints, preset=conditions.checkpoint_preset, device=device),
            "plm": make_policy("plm", checkpoints, latency_source=conditions.latency_source,
                               preset=conditions.checkpoint_preset, device=device)}
