"""While a check runs the student's code, the kit's own implementation of that exercise is switched off.

A lesson asks students to write, for example, PLM-Net's Algorithm 1; the kit has one
(``interpolate_actions``). Calling it would pass every check without writing anything, so
:func:`blocked_references` replaces each reference implementation of the exercise under test by a
tripwire for the duration of one call of the student's code; the check then fails with "you called
plm_highway's own ...: write it yourself".

:data:`REFERENCES` is the list, one entry per reference implementation: when a function moves or is
renamed, change its ``name`` here (``tests/test_lessons_delegation.py`` fails on an entry that no longer
resolves). How a target is switched off:

* a Python function: its ``__code__`` is swapped, so every reference to it (``from x import f`` in the
  notebook, an alias, a module attribute) trips;
* a class: its ``__init__`` is replaced, so every instantiation trips;
* anything else (a numba dispatcher, an ``lru_cache`` wrapper): every binding of the object in the kit's
  modules, the notebook's namespace and the student function's globals is replaced.

Tripping is recorded even if the student's code swallows the exception.
"""

from __future__ import annotations

import contextlib
import importlib
import sys
import types
from collections.abc import Iterator
from dataclasses import dataclass

TRIPWIRE_GLOBAL = "__plm_highway_tripwire__"


@dataclass(frozen=True)
class Reference:
    """One of the kit's implementations of what exercise ``exercise`` asks students to write."""

    exercise: str  # "lesson2.interpolate": the lesson's module and the student's function or class
    name: str  # "module.path:qualified_name" (or a third-party library's, where it does the same job)
    what: str  # how the failure names it to a student


REFERENCES: tuple[Reference, ...] = (
    # Lesson 1: the delay buffer and the drive with late snapshots
    Reference("lesson1.DelayBuffer", "plm_highway.latency.wrapper:LatencyWrapper", "latency wrapper"),
    Reference("lesson1.drive_with_latency", "plm_highway.rollout.closed_loop:drive", "closed-loop driver"),
    Reference("lesson1.drive_with_latency", "plm_highway.rollout.closed_loop:make_env", "delayed environment"),
    Reference("lesson1.drive_with_latency", "plm_highway.latency.wrapper:LatencyWrapper", "latency wrapper"),
    # Lesson 2: future labels, the TAPM heads, Algorithm 1
    Reference("lesson2.future_labels", "plm_highway.training.labels:future_steering_labels", "future labels"),
    Reference("lesson2.future_labels", "plm_highway.training.labels:_episode_future_labels", "future labels"),
    Reference("lesson2.TAPMHeads", "plm_highway.models.tapm:GroupedLinear", "batched head layer"),
    Reference("lesson2.TAPMHeads", "plm_highway.models.tapm:TAPM", "TAPM"),
    Reference("lesson2.interpolate", "plm_highway.models.plm_net:interpolate_actions", "Algorithm 1"),
    Reference("lesson2.interpolate", "plm_highway.models.plm_net:interpolate_batch", "Algorithm 1"),
    # Lesson 3: steering errors, Frechet distance, resampling, the Table 3 runs, lane keeping at 0.25 s
    Reference("lesson3.steering_errors", "plm_highway.metrics.steering:steering_errors", "steering errors"),
    Reference("lesson3.steering_errors", "plm_highway.evaluation.comparison:steering_comparison", "steering errors"),
    Reference("lesson3.steering_errors", "plm_highway.metrics.steering:steering_mae", "MAE"),
    Reference("lesson3.steering_errors", "plm_highway.metrics.steering:steering_mse", "MSE"),
    Reference("lesson3.steering_errors", "plm_highway.metrics.steering:steering_rmse", "RMSE"),
    Reference("lesson3.steering_errors", "plm_highway.metrics.similarity:mae", "MAE"),
    Reference("lesson3.steering_errors", "plm_highway.metrics.similarity:mse", "MSE"),
    Reference("lesson3.reduction_pct", "plm_highway.metrics.steering:reduction_pct", "error reduction"),
    Reference("lesson3.discrete_frechet", "plm_highway.metrics.curves:frechet_dist", "Frechet distance"),
    Reference("lesson3.discrete_frechet", "similaritymeasures:frechet_dist", "Frechet distance"),
    Reference("lesson3.resample", "plm_highway.metrics.curves:resample_by_arc_length", "arc-length resampling"),
    Reference("lesson3.drive_table_3", "plm_highway.grading.lesson3:kit_table_3_runs", "Table 3 runs"),
    Reference("lesson3.drive_table_3", "plm_highway.evaluation.reproduce:run_track", "Table 3 runs"),
    Reference("lesson3.lane_keeping", "plm_highway.metrics.similarity:mse", "mean square"),
    Reference("lesson3.trap_table", "plm_highway.evaluation.comparison:steering_comparison", "steering errors"),
    Reference("lesson3.trap_table", "plm_highway.evaluation.outcomes:run_outcomes", "run outcomes"),
    Reference("lesson3.trap_table", "plm_highway.metrics.steering:steering_errors", "steering errors"),
    Reference("lesson3.trap_table", "plm_highway.metrics.steering:reduction_pct", "error reduction"),
    # Lesson 4: the simulator's replay, mismatch windows, the two hypotheses, the fit
    Reference("lesson4.replay_yaw_rate", "plm_highway.vehicle.kinematic:kinematic_bicycle_rates", "kinematic bicycle"),
    Reference("lesson4.replay_yaw_rate", "plm_highway.sim2real.physics.replay:model_yaw_rate", "yaw-rate replay"),
    Reference("lesson4.replay_yaw_rate", "plm_highway.sim2real.physics.effects:simulate_yaw_rate", "yaw-rate replay"),
    Reference("lesson4.replay_yaw_rate", "plm_highway.grading.lesson4:reference_yaw_rate", "yaw-rate replay"),
    Reference("lesson4.mismatch_windows", "plm_highway.sim2real.diagnose:mismatch_windows", "mismatch windows"),
    Reference("lesson4.mismatch_windows", "plm_highway.grading.lesson4:reference_windows", "mismatch windows"),
    Reference("lesson4.delayed_yaw_rate", "plm_highway.sim2real.physics.effects:simulate_yaw_rate", "delay model"),
    Reference("lesson4.delayed_yaw_rate", "plm_highway.sim2real.physics.replay:model_yaw_rate", "delay model"),
    Reference("lesson4.delayed_yaw_rate", "plm_highway.grading.lesson4:reference_delayed", "delay model"),
    Reference("lesson4.understeer_yaw_rate", "plm_highway.sim2real.physics.effects:simulate_yaw_rate", "tire model"),
    Reference("lesson4.understeer_yaw_rate", "plm_highway.sim2real.physics.replay:model_yaw_rate", "tire model"),
    Reference("lesson4.fit_on_grid", "plm_highway.sim2real.fit.selection:fit_candidates", "effect fit"),
    Reference("lesson4.fit_on_grid", "plm_highway.sim2real.fit.polish:least_squares", "effect fit"),
    # Lesson 5: re-stamping a late camera measurement, re-estimating from its capture step to now
    Reference("lesson5.capture_index", "plm_highway.lane_ekf.ekf:LaneStateEstimator._index_at", "capture step"),
    Reference("lesson5.capture_index", "plm_highway.grading.lesson5:reference_capture_index", "capture step"),
    Reference("lesson5.reestimate", "plm_highway.lane_ekf.ekf:reestimate", "re-estimation"),
    Reference("lesson5.reestimate", "plm_highway.grading.lesson5:reference_reestimate", "re-estimation"),
    Reference("lesson5.fuse_late", "plm_highway.lane_ekf.ekf:LaneStateEstimator.add_camera", "delay compensation"),
    Reference("lesson5.fuse_late", "plm_highway.lane_ekf.ekf:reestimate", "re-estimation"),
    Reference("lesson5.fuse_late", "plm_highway.grading.lesson5:reference_fuse_late", "delay compensation"),
    Reference("lesson5.fuse_late", "plm_highway.grading.lesson5:reference_reestimate", "re-estimation"),
    # Lesson 5, part 7: the hidden latency
    Reference("lesson5.alignment_cost", "plm_highway.grading.lesson5:reference_alignment_cost", "alignment cost"),
    Reference("lesson5.alignment_cost", "plm_highway.grading.lesson5:reference_heading", "integrated heading"),
    Reference("lesson5.alignment_cost", "plm_highway.latency.estimate:fit_alignment", "alignment cost"),
    Reference("lesson5.estimate_latency", "plm_highway.grading.lesson5:reference_estimate_latency", "latency estimate"),
    Reference("lesson5.estimate_latency", "plm_highway.grading.lesson5:reference_alignment_cost", "alignment cost"),
    Reference("lesson5.estimate_latency", "plm_highway.latency.estimate:estimate_stream", "latency estimator"),
    Reference("lesson5.estimate_latency", "plm_highway.latency.estimate:LatencyEstimator", "latency estimator"),
    Reference("lesson5.estimate_latency", "plm_highway.latency.estimate:fit_alignment", "alignment cost"),
    Reference("lesson5.relative_dip", "plm_highway.grading.lesson5:reference_relative_dip", "relative dip"),
)


class DelegationDetected(Exception):  # the name is what happened
    def __init__(self, reference: Reference):
        super().__init__(f"{reference.name} is switched off while this check runs")
        self.reference = reference


def resolve(name: str):
    """The object ``module.path:qualified.name`` names; ``LookupError`` if it does not exist (any more)."""
    module_name, _, qualname = name.partition(":")
    try:
        target = importlib.import_module(module_name)
    except ImportError as error:
        raise LookupError(f"{name}: module {module_name} cannot be imported ({error})") from None
    for part in qualname.split("."):
        try:
            target = getattr(target, part)
        except AttributeError:
            raise LookupError(f"{name}: {part!r} not found") from None
    return target


def references_for(exercise: str | None) -> list[Reference]:
    return [reference for reference in REFERENCES if reference.exercise == exercise] if exercise else []


@contextlib.contextmanager
def blocked_references(exercise: str | None, student_function=None) -> Iterator[list[Reference]]:
    """Switch off the kit's implementations of ``exercise``; yields the list of those that were called."""
    tripped: list[Reference] = []
    undo: list = []
    try:
        for reference in references_for(exercise):
            try:
                target = resolve(reference.name)
            except LookupError:
                continue  # renamed elsewhere: the delegation test reports it, students are not stopped
            undo.append(_switch_off(target, reference, tripped, student_function))
        yield tripped
    finally:
        for restore in reversed(undo):
            restore()


def _switch_off(target, reference: Reference, tripped: list[Reference], student_function):
    def trip(*args, **kwargs):
        tripped.append(reference)
        raise DelegationDetected(reference)

    if isinstance(target, type):
        had_own = "__init__" in target.__dict__
        original = target.__dict__.get("__init__")
        target.__init__ = trip

        def restore_class():
            if had_own:
                target.__init__ = original
            else:
                del target.__init__
        return restore_class
    if isinstance(target, types.FunctionType) and not target.__code__.co_freevars:
        return _swap_code(target, reference, tripped)
    return _rebind(target, trip, student_function)


def _swap_code(function: types.FunctionType, reference: Reference, tripped: list[Reference]):
    label = reference.name
    source = f"def {function.__name__}(*args, **kwargs):\n    raise {TRIPWIRE_GLOBAL}({label!r})\n"
    namespace: dict = {}
    exec(compile(source, f"<{label} switched off>", "exec"), namespace)  # a fixed two-line stub
    original_code = function.__code__
    function_globals = function.__globals__
    raisers = function_globals.setdefault(TRIPWIRE_GLOBAL, _Raisers())
    raisers.push(label, reference, tripped)
    function.__code__ = namespace[function.__name__].__code__

    def restore_function():
        function.__code__ = original_code
        raisers.pop(label)
        if not raisers:
            function_globals.pop(TRIPWIRE_GLOBAL, None)
    return restore_function


class _Raisers(dict):
    """label -> (reference, tripped list): what a swapped-out function raises, per label."""

    def push(self, label, reference, tripped):
        self.setdefault(label, []).append((reference, tripped))

    def pop(self, label):
        stack = self[label]
        stack.pop()
        if not stack:
            del self[label]

    def __call__(self, label):
        reference, tripped = self[label][-1]
        tripped.append(reference)
        return DelegationDetected(reference)


def _namespaces(student_function) -> list[dict]:
    spaces = [vars(module) for name, module in list(sys.modules.items())
              if module is not None and (name == "__main__" or name.startswith("plm_highway"))]
    try:
        shell = sys.modules["IPython"].get_ipython() if "IPython" in sys.modules else None
    except Exception:  # no IPython shell: nothing to add
        shell = None
    if shell is not None:
        spaces.append(shell.user_ns)
    function = getattr(student_function, "__func__", student_function)
    if isinstance(function, types.FunctionType):
        spaces.append(function.__globals__)
    elif isinstance(student_function, type):
        for attribute in vars(student_function).values():
            if isinstance(attribute, types.FunctionType):
                spaces.append(attribute.__globals__)
    return spaces


def _rebind(target, replacement, student_function):
    rebound: list[tuple[dict, str]] = []
    seen: set[int] = set()
    for space in _namespaces(student_function):
        if id(space) in seen:
            continue
        seen.add(id(space))
        for key, value in list(space.items()):
            if value is target:
                space[key] = replacement
                rebound.append((space, key))

    def restore_bindings():
        for space, key in rebound:
            space[key] = target
    return restore_bindings
