"""Graded checks for Lesson 2, "Teaching a car to look ahead".

Three pieces of PLM-Net: the TAPM's future-action labels (looked up by time), the TAPM's heads
(N sub-models run as one batched computation) and Algorithm 1 (linear interpolation in latency).
Expected values in the hand-made cases were worked out by hand and are written out below; the
checks on larger inputs compare with the package's implementation, computed before the student's
code runs (while it runs, the package's implementation is switched off). A ``seed`` (nbgrader's
hidden tests) draws further cases.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch
from torch import nn
from torch.overrides import TorchFunctionMode

from plm_highway.grading.checks import CheckFailed, call_student, expect_close, expect_true, format_number, graded
from plm_highway.models.plm_net import interpolate_actions
from plm_highway.models.tapm import DEFAULT_DELTA_GRID_S
from plm_highway.training.labels import future_steering_labels

# --- Exercise A: future labels -----------------------------------------------------------------------

# Two episodes, listed 5 then 2, each with its own clock starting at 0. Episode 5 lost its frame at 0.15 s.
HAND_T_S = np.array([0.00, 0.05, 0.10, 0.20, 0.25, 0.00, 0.05, 0.10, 0.15])
HAND_EPISODE_ID = np.array([5, 5, 5, 5, 5, 2, 2, 2, 2])
HAND_STEERING = np.array([0.0, 0.1, 0.3, 0.2, -0.2, -0.5, -0.4, -0.3, -0.1])
HAND_DELTAS_S = (0.05, 0.10)
# A row is valid when t + 0.10 is still inside its own episode (episode 5 ends at 0.25 s, episode 2 at 0.15 s).
HAND_VALID = np.array([True, True, True, False, False, True, True, False, False])
HAND_LABELS = np.array([  # the valid rows only, worked out by hand
    [0.1, 0.3],  # episode 5, t = 0.00: steering at 0.05 s and 0.10 s
    [0.3, 0.25],  # episode 5, t = 0.05: no frame at 0.15 s, halfway between 0.3 (0.10 s) and 0.2 (0.20 s)
    [0.25, 0.2],  # episode 5, t = 0.10: 0.15 s (interpolated as above) and 0.20 s
    [-0.4, -0.3],  # episode 2, t = 0.00
    [-0.3, -0.1],  # episode 2, t = 0.05
])


def _call_future_labels(future_labels, t_s, episode_id, steering, deltas_s):
    result = call_student(future_labels, t_s, episode_id, steering, deltas_s,
                          what=f"future_labels(...) on {len(t_s)} rows, deltas_s = {tuple(deltas_s)}",
                          exercise="lesson2.future_labels")
    expect_true(isinstance(result, tuple) and len(result) == 2,
                f"future_labels must return a tuple (labels, valid), received {type(result).__name__}")
    labels, valid = np.asarray(result[0], dtype=float), np.asarray(result[1])
    n_rows, n_deltas = len(t_s), len(deltas_s)
    expect_true(labels.shape == (n_rows, n_deltas),
                f"labels: expected shape {(n_rows, n_deltas)} (one row per sample, one column per delta), "
                f"received {labels.shape}")
    expect_true(valid.shape == (n_rows,) and valid.dtype == bool,
                f"valid: expected a boolean array of shape {(n_rows,)}, received {valid.dtype} {valid.shape}",
                hint="one True/False per row: does the row have a future label for every delta?")
    return labels, valid


@graded(points=2)
def check_future_labels_by_hand(future_labels, seed: int | None = None) -> None:
    """Two tiny episodes with a dropped frame: labels by time, never across an episode's end."""
    if seed is not None:
        _random_episode_cases(future_labels, np.random.default_rng(seed))
        return
    labels, valid = _call_future_labels(future_labels, HAND_T_S, HAND_EPISODE_ID, HAND_STEERING, HAND_DELTAS_S)
    for row in range(len(HAND_T_S)):
        where = f"row {row} (episode {HAND_EPISODE_ID[row]}, t = {HAND_T_S[row]:.2f} s)"
        expect_true(bool(valid[row]) == bool(HAND_VALID[row]),
                    f"{where}: expected valid={bool(HAND_VALID[row])}, received {bool(valid[row])}",
                    hint="a row is valid only if t + max(deltas) is at or before the last time of ITS OWN "
                         "episode (compare with a 1e-6 s tolerance); the next rows may belong to another episode")
    for expected, row in zip(HAND_LABELS, np.flatnonzero(HAND_VALID)):
        expect_close(f"labels of row {row} (episode {HAND_EPISODE_ID[row]}, t = {HAND_T_S[row]:.2f} s) "
                     f"for deltas {HAND_DELTAS_S}", expected, labels[row], atol=1e-6,
                     hint="look the steering up at TIME t + delta (np.interp over the episode's own t_s and "
                          "steering), do not count rows: episode 5 has no frame at 0.15 s")


@graded(points=2)
def check_future_labels_on_data(future_labels, steps: dict) -> None:
    """The collected dataset: the same labels and valid rows as the kit's training uses."""
    t_s, episode_id, steering = steps["t_s"], steps["episode_id"], steps["steering"]
    expected, expected_valid = future_steering_labels(episode_id, t_s, steering, DEFAULT_DELTA_GRID_S)
    labels, valid = _call_future_labels(future_labels, t_s, episode_id, steering, DEFAULT_DELTA_GRID_S)
    wrong = np.flatnonzero(valid != expected_valid)
    if len(wrong):
        row = int(wrong[0])
        raise CheckFailed(f"valid on the collected data ({len(t_s)} rows)", f"{int(expected_valid.sum())} valid rows",
                          f"{int(valid.sum())} valid rows",
                          f"the last {max(DEFAULT_DELTA_GRID_S)} s of each episode have no future",
                          [f"first difference at row {row} (episode {episode_id[row]}, t = {t_s[row]:.2f} s): "
                           f"expected {bool(expected_valid[row])}, received {bool(valid[row])}"])
    rows = np.flatnonzero(expected_valid)
    expect_close(f"labels of the {len(rows)} valid rows of the collected data", expected[rows], labels[rows],
                 atol=1e-5, hint="column j is the steering at t + deltas_s[j] of the same episode")


def _random_episode_cases(future_labels, rng: np.random.Generator) -> None:
    """Episodes in shuffled order, each with its own clock, rate and dropped frames; random deltas."""
    t_parts, id_parts = [], []
    for episode in rng.permutation(7):
        dt_s = float(rng.choice([0.05, 0.1, 0.04]))
        t_s = np.arange(int(rng.integers(3, 30))) * dt_s
        keep = np.ones(len(t_s), bool)
        keep[1:-1] = rng.random(len(t_s) - 2) > 0.2
        t_parts.append(np.round(t_s[keep], 6))
        id_parts.append(np.full(int(keep.sum()), int(episode) * 3 + 1))
    t_s, episode_id = np.concatenate(t_parts), np.concatenate(id_parts)
    steering = rng.uniform(-1, 1, len(t_s))
    deltas_s = tuple(sorted(float(d) for d in rng.choice([0.05, 0.1, 0.15, 0.2, 0.25, 0.3], 3, replace=False)))
    expected, expected_valid = future_steering_labels(episode_id, t_s, steering, deltas_s)
    labels, valid = _call_future_labels(future_labels, t_s, episode_id, steering, deltas_s)
    wrong = np.flatnonzero(valid != expected_valid)
    if len(wrong):
        row = int(wrong[0])
        raise CheckFailed(f"valid on {len(t_s)} rows of 7 shuffled episodes with dropped frames, deltas {deltas_s}",
                          f"valid[{row}] = {bool(expected_valid[row])}", f"valid[{row}] = {bool(valid[row])}",
                          f"row {row} is episode {episode_id[row]} at t = {t_s[row]:g} s; a row is valid only if "
                          "t + max(deltas) is at or before the last time of its own episode",
                          [f"{len(wrong)} of {len(t_s)} rows differ"])
    rows = np.flatnonzero(expected_valid)
    expect_close(f"labels of the valid rows of 7 shuffled episodes with dropped frames, deltas {deltas_s}",
                 expected[rows], labels[rows], atol=1e-5,
                 hint="interpolate the steering at t + delta within the row's own episode (np.interp)")


# --- Exercise B: the TAPM heads ---------------------------------------------------------------------

HEAD_IN_FEATURES = 700  # a_BM -> 100, z_o -> 500, z_v -> 100, concatenated
HEAD_WIDTHS = (200, 100, 50, 1)
# Worked out by hand, weights + biases of FC 700->200, 200->100, 100->50, 50->1:
# (700 * 200 + 200) + (200 * 100 + 100) + (100 * 50 + 50) + (50 * 1 + 1) = 140,200 + 20,100 + 5,050 + 51.
PARAMS_PER_HEAD = 165_401


def _layer_shapes(n_heads: int) -> list[tuple[tuple[int, ...], tuple[int, ...]]]:
    widths = (HEAD_IN_FEATURES, *HEAD_WIDTHS)
    return [((n_heads, fan_in, fan_out), (n_heads, fan_out)) for fan_in, fan_out in itertools.pairwise(widths)]


def _make_heads(heads_class, n_heads: int):
    heads = call_student(heads_class, n_heads, what=f"TAPMHeads({n_heads})", exercise="lesson2.TAPMHeads")
    expect_true(isinstance(heads, nn.Module), f"TAPMHeads({n_heads}) must be a torch.nn.Module",
                hint="class TAPMHeads(nn.Module) and call super().__init__() first")
    for name in ("weights", "biases"):
        container = getattr(heads, name, None)
        expect_true(isinstance(container, nn.ParameterList) and len(container) == 4,
                    f"TAPMHeads.{name} must be an nn.ParameterList of 4 tensors (one per layer), received "
                    f"{type(container).__name__}" + (f" of length {len(container)}" if container is not None else ""),
                    hint="self.weights = nn.ParameterList([...]) so that the optimizer sees the parameters")
    for layer, (weight_shape, bias_shape) in enumerate(_layer_shapes(n_heads)):
        for name, tensor, expected in (("weights", heads.weights[layer], weight_shape),
                                       ("biases", heads.biases[layer], bias_shape)):
            expect_true(tuple(tensor.shape) == expected,
                        f"with {n_heads} heads, {name}[{layer}] must have shape {expected}, received "
                        f"{tuple(tensor.shape)}", hint="weights[k] is (n_heads, in, out), biases[k] is (n_heads, out)")
    return heads


def _forward(heads, x: torch.Tensor) -> torch.Tensor:
    output = call_student(heads, x, what=f"TAPMHeads.forward on a batch of shape {tuple(x.shape)}",
                          exercise="lesson2.TAPMHeads")
    expect_true(isinstance(output, torch.Tensor), f"forward must return a torch.Tensor, received {type(output).__name__}")
    return output


@graded(points=2)
def check_tapm_heads_shapes(heads_class) -> None:
    """Parameter layout and count, output shape and range, gradients reach every parameter."""
    for n_heads in (5, 1):
        # Seeded, so that a run of this check does not depend on what drew from torch's generator before it.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(n_heads)
            heads = _make_heads(heads_class, n_heads)
        n_params = sum(p.numel() for p in heads.parameters())
        expect_close(f"number of parameters with {n_heads} heads", n_heads * PARAMS_PER_HEAD, n_params, atol=0,
                     hint=f"each head has {PARAMS_PER_HEAD:,} = (700*200+200) + (200*100+100) + (100*50+50) + "
                          "(50*1+1) parameters, and nothing else is a parameter")
        for layer, (fan_in, weight) in enumerate(zip((HEAD_IN_FEATURES, *HEAD_WIDTHS[:-1]), heads.weights)):
            bound = 1 / np.sqrt(fan_in)
            values = torch.cat([weight.detach().ravel(), heads.biases[layer].detach().ravel()])
            # A uniform sample's std falls below 0.45 of the bound now and then when it is small (the last layer of
            # one head holds 51 values), so the floor is also kept 5 standard errors below the expected std.
            expected_std = bound / np.sqrt(3)
            min_std = min(0.45 * bound, expected_std * (1 - 5 * np.sqrt(0.8 / (4 * values.numel()))))
            expect_true(bool(values.abs().max() <= bound + 1e-6) and float(values.std()) > min_std,
                        f"initial weights and biases of layer {layer} with {n_heads} heads (fan-in {fan_in})",
                        "initialise like nn.Linear: uniform in [-1/sqrt(fan_in), 1/sqrt(fan_in)]",
                        expected=f"uniform in +-{format_number(bound)} (std {format_number(bound / np.sqrt(3))})",
                        received=f"largest |value| {format_number(float(values.abs().max()))}, std "
                                 f"{format_number(float(values.std()))}")
        heads.eval()
        x = torch.randn(7, HEAD_IN_FEATURES, generator=torch.Generator().manual_seed(n_heads))
        output = _forward(heads, x)
        expect_true(tuple(output.shape) == (7, n_heads),
                    f"a batch of 7 inputs of 700 features with {n_heads} heads must give shape (7, {n_heads}), "
                    f"received {tuple(output.shape)}", hint="(batch, n_heads): squeeze only the last axis of size 1")
        expect_true(bool(torch.all(output.abs() < 1)), "outputs must lie in (-1, 1)", hint="the last layer is tanh")
        heads.train()
        _forward(heads, x).sum().backward()
        missing = [name for name, p in heads.named_parameters() if p.grad is None or not torch.any(p.grad != 0)]
        expect_true(not missing, f"no gradient reached {missing}",
                    hint="compute with the nn.Parameters themselves (no .data, .detach() or numpy)")


def _reference_heads(n_heads: int, dropout: float, seed: int) -> list[nn.Sequential]:
    """N independent sub-models written the plain way, one nn.Sequential per head."""
    torch.manual_seed(seed)
    return [nn.Sequential(nn.Linear(700, 200), nn.ReLU(), nn.Dropout(dropout), nn.Linear(200, 100), nn.ReLU(),
                          nn.Dropout(dropout), nn.Linear(100, 50), nn.Tanh(), nn.Linear(50, 1), nn.Tanh()).eval()
            for _ in range(n_heads)]


def _copy_reference_into(heads, reference: list[nn.Sequential]) -> None:
    with torch.no_grad():
        for head, sequential in enumerate(reference):
            linears = [module for module in sequential if isinstance(module, nn.Linear)]
            for layer, linear in enumerate(linears):
                heads.weights[layer][head].copy_(linear.weight.T)  # nn.Linear stores (out, in)
                heads.biases[layer][head].copy_(linear.bias)


class _CountTorchCalls(TorchFunctionMode):
    def __init__(self):
        super().__init__()
        self.count = 0

    def __torch_function__(self, func, types, args=(), kwargs=None):
        self.count += 1
        return func(*args, **(kwargs or {}))


@graded(points=3)
def check_tapm_heads_are_independent(heads_class) -> None:
    """Equal to N separate sub-models given the same weights; own dropout masks; no loop over heads."""
    n_heads = 3
    heads = _make_heads(heads_class, n_heads)
    reference = _reference_heads(n_heads, dropout=0.3, seed=2)
    _copy_reference_into(heads, reference)
    heads.eval()
    x = torch.randn(16, HEAD_IN_FEATURES, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        output = _forward(heads, x)
        expected = torch.cat([sequential(x) for sequential in reference], dim=1)
    expect_true(tuple(output.shape) == (16, n_heads), f"expected output shape (16, 3), received {tuple(output.shape)}")
    for head in range(n_heads):
        expect_close(f"eval-mode output of head {head} (weights[k][{head}], biases[k][{head}]) on 16 inputs",
                     expected[:, head].numpy(), output[:, head].numpy(), atol=1e-5,
                     hint="per head: x @ W0 + b0, ReLU, dropout, @ W1 + b1, ReLU, dropout, @ W2 + b2, tanh, "
                          "@ W3 + b3, tanh; head h uses only weights[k][h] and biases[k][h]")
    with torch.no_grad():
        again = _forward(heads, x)
    expect_true(torch.equal(output, again), "in eval mode two forward passes on the same input differ",
                hint="dropout must be off in eval mode: F.dropout(h, p, training=self.training)")
    # Identical weights in every head: in train mode only the dropout masks can tell the heads apart.
    _copy_reference_into(heads, [reference[0]] * n_heads)
    heads.train()
    torch.manual_seed(4)
    with torch.no_grad():
        trained = _forward(heads, x)
    expect_true(not torch.allclose(trained, output[:, :1].expand(-1, n_heads)),
                "in train mode the output equals the eval-mode output", hint="apply dropout (p = 0.3) in train mode")
    expect_true(not torch.allclose(trained[:, 0], trained[:, 1]),
                "with identical weights in every head, train-mode outputs of heads 0 and 1 are equal",
                hint="each head must drop its own units: apply dropout to the (batch, n_heads, width) tensor")
    counts = {}
    for n in (2, 6):
        counted = _make_heads(heads_class, n).eval()
        with torch.no_grad(), _CountTorchCalls() as counter:
            _forward(counted, x)
        counts[n] = counter.count
    expect_true(counts[2] == counts[6],
                f"forward made {counts[2]} torch calls with 2 heads and {counts[6]} with 6: it loops over heads",
                hint="one batched operation per layer for all heads, e.g. torch.einsum('bni,nio->bno', h, W)")


# --- Exercise C: Algorithm 1 ------------------------------------------------------------------------

HAND_DELTA_REF_S = np.array([0.0, 0.15, 0.20, 0.25, 0.30, 0.35])
HAND_A_ROW = np.array([0.10, 0.40, 0.30, -0.20, 0.00, 0.50])  # [a_BM, heads at 0.15 ... 0.35 s]
HAND_B_ROW = np.array([-0.30, -0.10, 0.20, 0.60, 0.80, 0.90])
# (latency, which row, expected action), worked out by hand.
HAND_CASES = [
    (0.0, "a", 0.10),  # zero latency: a_BM
    (0.075, "a", 0.25),  # halfway between 0 and 0.15: 0.10 + 0.5 * (0.40 - 0.10)
    (0.15, "a", 0.40),  # on the grid: that head
    (0.18, "a", 0.34),  # 0.6 of the way from 0.15 to 0.20: 0.40 + 0.6 * (0.30 - 0.40)
    (0.25, "a", -0.20),  # on the grid
    (0.27, "a", -0.12),  # 0.4 of the way from 0.25 to 0.30: -0.20 + 0.4 * (0.00 + 0.20)
    (0.325, "a", 0.25),  # halfway between 0.30 and 0.35: 0.00 + 0.5 * 0.50
    (0.35, "a", 0.50),  # the last grid value
    (0.50, "a", 0.50),  # above the grid: the last head
    (0.03, "b", -0.26),  # 0.2 of the way from 0 to 0.15: -0.30 + 0.2 * (-0.10 + 0.30)
    (0.22, "b", 0.36),  # 0.4 of the way from 0.20 to 0.25: 0.20 + 0.4 * (0.60 - 0.20)
    (1.00, "b", 0.90),  # far above the grid: the last head
]


def _call_interpolate(interpolate, latency_s, delta_ref_s, a_ref) -> np.ndarray:
    result = call_student(interpolate, latency_s, delta_ref_s, a_ref,
                          what=f"interpolate(latency_s, delta_ref_s, a_ref) for {len(latency_s)} latencies",
                          exercise="lesson2.interpolate")
    try:
        result = np.asarray(result, dtype=float)
    except (TypeError, ValueError):
        raise CheckFailed("what interpolate returned", "a numpy array of floats", type(result).__name__) from None
    expect_true(result.shape == (len(latency_s),),
                f"for {len(latency_s)} latencies interpolate must return shape ({len(latency_s)},), received "
                f"{result.shape}", hint="one action per row of a_ref")
    return result


@graded(points=3)
def check_interpolate_by_hand(interpolate) -> None:
    """Between grid values, on them, above the last one: values worked out by hand."""
    latency_s = np.array([latency for latency, _, _ in HAND_CASES])
    a_ref = np.stack([HAND_A_ROW if row == "a" else HAND_B_ROW for _, row, _ in HAND_CASES])
    received = _call_interpolate(interpolate, latency_s, HAND_DELTA_REF_S.copy(), a_ref.copy())
    for index, (latency, _, expected) in enumerate(HAND_CASES):
        if latency > HAND_DELTA_REF_S[-1]:
            hint = "above the last grid value, return the last head's action (no extrapolation)"
        elif np.any(np.isclose(latency, HAND_DELTA_REF_S, rtol=0, atol=1e-12)):
            hint = "a latency on the grid returns that grid entry's action"
        else:
            hint = ("find j with delta_ref[j] < latency <= delta_ref[j + 1], then a[j] + (latency - delta_ref[j]) / "
                    "(delta_ref[j + 1] - delta_ref[j]) * (a[j + 1] - a[j]), using the row's OWN actions")
        expect_close(f"interpolate at latency {latency} s (row {index}, a_ref = {np.round(a_ref[index], 2).tolist()})",
                     expected, received[index], atol=1e-9, hint=hint)


@graded(points=1)
def check_interpolate_rejects_bad_latency(interpolate) -> None:
    """NaN or negative latency is a bug upstream: ValueError, never a silent action."""
    a_ref = np.tile(HAND_A_ROW, (3, 1))
    for bad in (np.nan, -0.05):
        latency_s = np.array([0.1, bad, 0.2])
        try:
            result = call_student(interpolate, latency_s, HAND_DELTA_REF_S.copy(), a_ref.copy(),
                                  what=f"interpolate({latency_s.tolist()}, ...)", exercise="lesson2.interpolate")
        except CheckFailed as failure:
            if failure.headline and failure.headline.startswith("your code raised ValueError"):
                continue
            raise
        raise CheckFailed(f"interpolate({latency_s.tolist()}, ...)", "ValueError", repr(result)[:80],
                          "`if not np.all(latency_s >= 0): raise ValueError(...)` catches NaN too")


@graded(points=2)
def check_interpolate_matches_package(interpolate, seed: int | None = None) -> None:
    """Random latencies (many on the grid) on two grids: equal to the kit's Algorithm 1."""
    rng = np.random.default_rng(7 if seed is None else seed)
    grids = [HAND_DELTA_REF_S, np.array([0.0, 0.1, 0.3, 0.4])]
    if seed is not None:
        grids = [np.concatenate([[0.0], np.sort(rng.choice(np.arange(1, 60) / 100, int(rng.integers(1, 8)),
                                                            replace=False))]) for _ in range(3)]
    for delta_ref_s in grids:
        n = 1000
        latency_s = rng.uniform(0.0, 0.6, size=n)
        on_grid = rng.random(n) < 0.2
        latency_s[on_grid] = rng.choice(delta_ref_s, size=int(on_grid.sum()))
        a_ref = rng.uniform(-1, 1, size=(n, len(delta_ref_s)))
        expected = interpolate_actions(latency_s, delta_ref_s, a_ref)
        received = _call_interpolate(interpolate, latency_s.copy(), delta_ref_s.copy(), a_ref.copy())
        wrong = np.flatnonzero(~np.isclose(received, expected, rtol=0, atol=1e-9))
        if len(wrong):
            i = int(wrong[0])
            raise CheckFailed(f"interpolate for {n} random latencies on delta_ref_s = "
                              "[" + ", ".join(format_number(v) for v in delta_ref_s) + "]",
                              f"{format_number(expected[i], received[i])} at latency {format_number(latency_s[i])} s "
                              f"(row {i})", format_number(received[i], expected[i]),
                              "do not assume the paper's grid or its spacing, use delta_ref_s as given",
                              [f"{len(wrong)} of {n} results differ"])


# --- Helpers for the notebook (not graded) -----------------------------------------------------------


def tapm_trunk(tapm, a_bm: torch.Tensor, z_o: torch.Tensor, z_v: torch.Tensor) -> torch.Tensor:
    """The 700 features a trained ``plm_highway.models.tapm.TAPM`` feeds its heads: (B, 700)."""
    trunk = torch.cat([tapm.action_fc(a_bm.view(-1, 1)), tapm.image_fc(z_o), tapm.speed_fc(z_v)], dim=1)
    return torch.relu(trunk)


def load_heads_from_tapm(heads, tapm) -> None:
    """Copy a trained TAPM's head weights into a module with the lesson's layout (weights[k] (N, in, out)).

    The package's TAPM holds its first head layer as one ``nn.Linear(700, N * 200)`` (head h owns
    output units h * 200 ... h * 200 + 199) and the others as ``GroupedLinear`` with weights
    (N, in, out) and biases (N, 1, out).
    """
    n_heads = tapm.config.n_heads
    first = tapm.heads_in
    with torch.no_grad():
        heads.weights[0].copy_(first.weight.view(n_heads, HEAD_WIDTHS[0], -1).transpose(1, 2))
        heads.biases[0].copy_(first.bias.view(n_heads, HEAD_WIDTHS[0]))
        for layer, grouped in enumerate((tapm.heads_hidden, tapm.heads_tanh, tapm.heads_out), start=1):
            heads.weights[layer].copy_(grouped.weight)
            heads.biases[layer].copy_(grouped.bias.squeeze(1))
