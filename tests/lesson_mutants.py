"""The mutation battery: plausible wrong student implementations, one entry per mutant.

Each mutant changes the worked solution of one lesson: ``old`` (text of a solution cell, found exactly
once) becomes ``new``; with ``old`` empty, ``new`` is code run after the solution cells (a rewrite of a
whole function). ``checks`` are the graded checks aimed at it: every one of them must fail on the
mutant (``tests/test_lessons_mutants.py``), and each check must catch at least 90% of the mutants aimed
at it. ``delegation`` mutants hand the work to the kit and must fail with "write it yourself".
``slow`` mutants drive the simulator (closed-loop checks).

To add a lesson (Lesson 5), add its mutants here with ``lesson="05"``; nothing else changes.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Mutant:
    lesson: str
    checks: tuple[str, ...]
    why: str
    old: str
    new: str
    delegation: bool = False
    slow: bool = False


BUFFER = ("check_delay_buffer",)
LABELS = ("check_future_labels_by_hand",)
HEADS_SHAPES = ("check_tapm_heads_shapes",)
HEADS = ("check_tapm_heads_are_independent",)
INTERP = ("check_interpolate_by_hand", "check_interpolate_matches_package")

MUTANTS: tuple[Mutant, ...] = (
    # ---------------- Lesson 1: the delay buffer ----------------
    Mutant("01", BUFFER, "missing tolerance: 1.0 - 0.35 is not exactly 0.65",
           "now_s - latency_s + 1e-9) - 1", "now_s - latency_s) - 1"),
    Mutant("01", BUFFER, "boundary: an item exactly latency_s old is excluded",
           "bisect.bisect_right(self.times_s, now_s - latency_s + 1e-9)",
           "bisect.bisect_left(self.times_s, now_s - latency_s - 1e-9)"),
    Mutant("01", ("check_delay_buffer", "check_growing_latency"), "off by one: the first item after the cut",
           "- 1\n        index = max(index, 0)", "\n        index = min(index, len(self.items) - 1)"),
    Mutant("01", BUFFER, "reports the requested latency as the age",
           "return self.items[index], now_s - self.times_s[index]", "return self.items[index], latency_s"),
    Mutant("01", BUFFER, "boundary: without enough history index -1 wraps to the newest item",
           "        index = max(index, 0)\n", ""),
    Mutant("01", BUFFER, "unbounded memory: never forgets",
           "        while len(self.times_s) > 1 and self.times_s[1] <= oldest_needed_s + 1e-9:\n"
           "            self.times_s.popleft()\n            self.items.popleft()\n", ""),
    Mutant("01", BUFFER, "forgets too much: drops the item at or before now - max_latency_s",
           "self.times_s[1] <= oldest_needed_s + 1e-9", "self.times_s[0] < oldest_needed_s"),
    Mutant("01", BUFFER, "counts frames instead of looking up by time",
           "index = bisect.bisect_right(self.times_s, now_s - latency_s + 1e-9) - 1",
           "index = len(self.items) - 1 - round(latency_s / 0.05)"),
    Mutant("01", BUFFER, "rounds the latency to the 0.05 s grid",
           "now_s - latency_s + 1e-9", "now_s - round(latency_s / 0.05) * 0.05 + 1e-9"),
    Mutant("01", BUFFER, "bounded by count (10 items), not by time",
           "while len(self.times_s) > 1 and self.times_s[1] <= oldest_needed_s + 1e-9:",
           "while len(self.times_s) > 10:"),
    Mutant("01", ("check_delay_buffer", "check_growing_latency"),
           "the original ROS FIFO: after the latency grows it serves fresher frames while the queue refills",
           "index = bisect.bisect_right(self.times_s, now_s - latency_s + 1e-9) - 1",
           "k = round(latency_s / 0.05)\n"
           "        self._since = 0 if getattr(self, '_k', k) != k else getattr(self, '_since', 0) + 1\n"
           "        self._k = k\n"
           "        index = len(self.items) - 1 - min(k, self._since)"),
    # ---------------- Lesson 1: driving with late snapshots ----------------
    Mutant("01", ("check_zigzag",), "ignores the latency", 'buffer.get(info["time_s"], latency_s)',
           'buffer.get(info["time_s"], 0.0)', slow=True),
    Mutant("01", ("check_zigzag",), "records the delayed (observed) offset, not the car's true one",
           'offsets_m.append(info["lateral_offset_m"])', 'offsets_m.append(snapshot.state["lateral_offset_m"])',
           slow=True),
    Mutant("01", ("check_zigzag",), "ignores duration_s and drives the whole track",
           "for _ in range(int(round(duration_s * 20))):", "for _ in range(10_000):", slow=True),
    Mutant("01", ("check_zigzag",), "delegates to the kit's closed loop", "",
           "def drive_with_latency(latency_s, seed=0, duration_s=25.0):\n"
           "    from plm_highway.rollout.closed_loop import drive\n"
           "    from plm_highway.expert import ExpertPolicy\n"
           "    log = drive('x', ExpertPolicy(), 'test', f'const:{latency_s}', seed, max_steps=round(duration_s * 20))\n"
           "    return log.columns['lateral_offset_m']", delegation=True, slow=True),
    # ---------------- Lesson 2: future labels ----------------
    Mutant("02", LABELS, "missing tolerance: 0.05 + 0.1 is not exactly 0.15",
           "t_s[rows[-1]] + 1e-6", "t_s[rows[-1]]"),
    Mutant("02", LABELS + ("check_future_labels_on_data",), "sign error: looks into the past",
           "t_s[rows, None] + deltas_s[None, :]", "t_s[rows, None] - deltas_s[None, :]"),
    Mutant("02", LABELS + ("check_future_labels_on_data",), "leaks across episodes",
           "rows = np.flatnonzero(episode_id == episode)", "rows = np.arange(len(t_s))"),
    Mutant("02", LABELS, "counts rows instead of looking up by time",
           "np.interp(target_s, t_s[rows], steering[rows])",
           "steering[rows][np.minimum(np.arange(len(rows))[:, None] + np.round(deltas_s / 0.05).astype(int)[None, :], "
           "len(rows) - 1)]"),
    Mutant("02", LABELS, "takes the next sample instead of interpolating",
           "np.interp(target_s, t_s[rows], steering[rows])",
           "steering[rows][np.minimum(np.searchsorted(t_s[rows], target_s - 1e-6), len(rows) - 1)]"),
    Mutant("02", LABELS, "boundary: strict inequality drops rows whose future is the last sample",
           "target_s <= t_s[rows[-1]] + 1e-6", "target_s < t_s[rows[-1]]"),
    Mutant("02", LABELS + ("check_future_labels_on_data",), "valid from the smallest delta only",
           "valid = ~np.isnan(labels).any(axis=1)", "valid = ~np.isnan(labels[:, 0])"),
    Mutant("02", LABELS, "compares with the last time of the whole array, not of the episode",
           "inside = target_s <= t_s[rows[-1]] + 1e-6", "inside = target_s <= t_s[-1] + 1e-6"),
    Mutant("02", LABELS + ("check_future_labels_on_data",), "delegates to the kit's labels", "",
           "def future_labels(t_s, episode_id, steering, deltas_s):\n"
           "    from plm_highway.training.labels import future_steering_labels\n"
           "    return future_steering_labels(np.asarray(episode_id), np.asarray(t_s, float), np.asarray(steering, float), "
           "deltas_s)", delegation=True),
    # ---------------- Lesson 2: the TAPM heads ----------------
    Mutant("02", HEADS_SHAPES, "initialises with N(0, 1)",
           ".uniform_(-bound, bound)))\n            self.biases", ".normal_(0, 1)))\n            self.biases"),
    Mutant("02", HEADS_SHAPES, "initialises the weights with zeros",
           "torch.empty(n_heads, fan_in, fan_out).uniform_(-bound, bound)", "torch.zeros(n_heads, fan_in, fan_out)"),
    Mutant("02", HEADS_SHAPES, "nn.Linear's (out, in) layout",
           "torch.empty(n_heads, fan_in, fan_out)", "torch.empty(n_heads, fan_out, fan_in)"),
    Mutant("02", HEADS_SHAPES, "biases shaped (n_heads, 1, out)",
           "torch.empty(n_heads, fan_out)", "torch.empty(n_heads, 1, fan_out)"),
    Mutant("02", HEADS_SHAPES, "squeezes every axis of size 1 (breaks a batch of one head)",
           ".squeeze(-1)", ".squeeze()"),
    Mutant("02", HEADS, "dropout also in eval mode",
           "hidden = F.dropout(hidden, self.dropout, training=self.training)\n"
           '        hidden = F.relu(torch.einsum("bni',
           "hidden = F.dropout(hidden, self.dropout, training=True)\n"
           '        hidden = F.relu(torch.einsum("bni'),
    Mutant("02", HEADS, "no dropout at all",
           "hidden = F.dropout(hidden, self.dropout, training=self.training)\n"
           '        hidden = F.relu(torch.einsum("bni,nio->bno", hidden, self.weights[1]) + self.biases[1])\n'
           "        hidden = F.dropout(hidden, self.dropout, training=self.training)\n",
           'hidden = F.relu(torch.einsum("bni,nio->bno", hidden, self.weights[1]) + self.biases[1])\n'),
    Mutant("02", HEADS, "one dropout mask shared by all heads",
           "hidden = F.dropout(hidden, self.dropout, training=self.training)\n"
           '        hidden = F.relu(torch.einsum("bni,nio->bno", hidden, self.weights[1]) + self.biases[1])\n'
           "        hidden = F.dropout(hidden, self.dropout, training=self.training)\n",
           "hidden = hidden * F.dropout(torch.ones_like(hidden[:, :1]), self.dropout, training=self.training)\n"
           '        hidden = F.relu(torch.einsum("bni,nio->bno", hidden, self.weights[1]) + self.biases[1])\n'
           "        hidden = hidden * F.dropout(torch.ones_like(hidden[:, :1]), self.dropout, training=self.training)\n"),
    Mutant("02", HEADS, "no tanh on the output",
           'return torch.tanh(torch.einsum("bni,nio->bno", hidden, self.weights[3]) + self.biases[3]).squeeze(-1)',
           'return (torch.einsum("bni,nio->bno", hidden, self.weights[3]) + self.biases[3]).squeeze(-1)'),
    Mutant("02", HEADS, "ReLU instead of tanh after the third layer",
           'hidden = torch.tanh(torch.einsum("bni,nio->bno", hidden, self.weights[2])',
           'hidden = F.relu(torch.einsum("bni,nio->bno", hidden, self.weights[2])'),
    Mutant("02", HEADS, "a Python loop over the heads", "",
           "def _looped_forward(self, x):\n"
           "    outputs = []\n"
           "    for h in range(self.n_heads):\n"
           "        z = F.dropout(F.relu(x @ self.weights[0][h] + self.biases[0][h]), self.dropout, training=self.training)\n"
           "        z = F.dropout(F.relu(z @ self.weights[1][h] + self.biases[1][h]), self.dropout, training=self.training)\n"
           "        z = torch.tanh(z @ self.weights[2][h] + self.biases[2][h])\n"
           "        outputs.append(torch.tanh(z @ self.weights[3][h] + self.biases[3][h]))\n"
           "    return torch.cat(outputs, dim=1)\n"
           "TAPMHeads.forward = _looped_forward"),
    # ---------------- Lesson 2: Algorithm 1 ----------------
    Mutant("02", INTERP, "extrapolates above the last grid value",
           "latency = np.minimum(latency_s, delta_ref_s[-1])", "latency = latency_s"),
    Mutant("02", ("check_interpolate_rejects_bad_latency",), "lets NaN through",
           "if not np.all(latency_s >= 0):", "if np.any(latency_s < 0):"),
    Mutant("02", ("check_interpolate_rejects_bad_latency",), "clips a negative latency to 0 instead of refusing it",
           "if not np.all(latency_s >= 0):", "latency_s = np.maximum(latency_s, 0.0)\n    if np.any(np.isnan(latency_s)):"),
    Mutant("02", INTERP, "uses the first row's actions for every row",
           "a_lo, a_hi = a_ref[rows, j], a_ref[rows, j + 1]", "a_lo, a_hi = a_ref[0, j], a_ref[0, j + 1]"),
    Mutant("02", ("check_interpolate_matches_package",), "assumes the paper's grid",
           "delta_ref_s = np.asarray(delta_ref_s, dtype=float)",
           "delta_ref_s = np.array([0.0, 0.15, 0.2, 0.25, 0.3, 0.35])"),
    Mutant("02", INTERP, "assumes an evenly spaced grid",
           'j = np.clip(np.searchsorted(delta_ref_s, latency, side="right") - 1, 0, len(delta_ref_s) - 2)',
           "j = np.clip(np.floor(latency / (delta_ref_s[1] - delta_ref_s[0])).astype(int), 0, len(delta_ref_s) - 2)"),
    Mutant("02", INTERP, "wrong denominator",
           "weight = (latency - delta_ref_s[j]) / (delta_ref_s[j + 1] - delta_ref_s[j])",
           "weight = (latency - delta_ref_s[j]) / delta_ref_s[j + 1]"),
    Mutant("02", INTERP, "off by one: the upper neighbour as j",
           'side="right") - 1, 0', 'side="right"), 0'),
    Mutant("02", INTERP, "rounds to the nearer grid value instead of interpolating",
           "return np.where(latency == delta_ref_s[j + 1], a_hi, a_lo + weight * (a_hi - a_lo))",
           "return np.where(weight < 0.5, a_lo, a_hi)"),
    Mutant("02", ("check_interpolate_by_hand",), "rounding: computes in float32",
           "a_ref = np.asarray(a_ref, dtype=float)", "a_ref = np.asarray(a_ref, dtype=np.float32)"),
    Mutant("02", INTERP, "delegates to the kit's Algorithm 1", "",
           "def interpolate(latency_s, delta_ref_s, a_ref):\n"
           "    from plm_highway.models.plm_net import interpolate_actions\n"
           "    return interpolate_actions(latency_s, delta_ref_s, a_ref)", delegation=True),
    # ---------------- Lesson 3: steering errors and reduction ----------------
    Mutant("03", ("check_steering_errors",), "MAE without the absolute value",
           "np.mean(np.abs(diff))", "abs(np.mean(diff))"),
    Mutant("03", ("check_steering_errors",), "mean instead of RMS for the RMSE",
           '"rmse": float(np.sqrt(mse))', '"rmse": float(np.mean(np.abs(diff)))'),
    Mutant("03", ("check_steering_errors",), "standard deviation instead of RMSE (removes the mean)",
           '"rmse": float(np.sqrt(mse))', '"rmse": float(np.std(diff))'),
    Mutant("03", ("check_steering_errors",), "divides by n - 1", "mse = float(np.mean(diff ** 2))",
           "mse = float(np.sum(diff ** 2) / (n - 1))"),
    Mutant("03", ("check_steering_errors",), "compares over the other run's length",
           "n = min(len(reference), len(other))", "n = len(other)"),
    Mutant("03", ("check_steering_errors",), "rounds the MAE to 4 decimals",
           '"mae": float(np.mean(np.abs(diff)))', '"mae": round(float(np.mean(np.abs(diff))), 4)'),
    Mutant("03", ("check_steering_errors",), "delegates to the kit", "",
           "def steering_errors(reference, other):\n"
           "    from plm_highway.metrics.steering import common_span, steering_errors as kit\n"
           "    return kit(*common_span(reference, other))", delegation=True),
    Mutant("03", ("check_reduction",), "relative to the mitigated error",
           "return 100.0 * (1.0 - mitigated_error / baseline_error)",
           "return 100.0 * (baseline_error - mitigated_error) / mitigated_error"),
    Mutant("03", ("check_reduction",), "a fraction, not %",
           "return 100.0 * (1.0 - mitigated_error / baseline_error)", "return 1.0 - mitigated_error / baseline_error"),
    Mutant("03", ("check_reduction",), "boundary: no guard for a zero baseline",
           "    if baseline_error == 0:\n        return 0.0\n", ""),
    Mutant("03", ("check_reduction",), "rounds to one decimal",
           "return 100.0 * (1.0 - mitigated_error / baseline_error)",
           "return round(100.0 * (1.0 - mitigated_error / baseline_error), 1)"),
    Mutant("03", ("check_reduction",), "sign error",
           "return 100.0 * (1.0 - mitigated_error / baseline_error)",
           "return 100.0 * (mitigated_error / baseline_error - 1.0)"),
    # ---------------- Lesson 3: Frechet distance ----------------
    Mutant("03", ("check_frechet", "check_trajectory_frechet"), "squared distances",
           "np.sqrt(((p[:, None, :] - q[None, :, :]) ** 2).sum(axis=2))", "((p[:, None, :] - q[None, :, :]) ** 2).sum(axis=2)"),
    Mutant("03", ("check_frechet",), "the first row is not cumulative",
           "                reach = current[j - 1]\n", "                reach = dist\n"),
    Mutant("03", ("check_frechet",), "adds up the couplings (DTW) instead of the maximum",
           "current[j] = max(reach, dist)", "current[j] = dist if i == j == 0 else reach + dist"),
    Mutant("03", ("check_frechet",), "forgets the diagonal step",
           "reach = min(previous[j], current[j - 1], previous[j - 1])", "reach = min(previous[j], current[j - 1])"),
    Mutant("03", ("check_frechet",), "Hausdorff-like: ignores the order of the points",
           "return float(previous[-1])", "return float(max(min(row) for row in d))"),
    Mutant("03", ("check_frechet",), "max instead of min over the predecessors",
           "reach = min(previous[j], current[j - 1], previous[j - 1])",
           "reach = max(previous[j], current[j - 1], previous[j - 1])"),
    Mutant("03", ("check_frechet",), "delegates to the kit", "",
           "def discrete_frechet(p, q):\n"
           "    from plm_highway.metrics import frechet_dist\n"
           "    return frechet_dist(p, q)", delegation=True),
    Mutant("03", ("check_frechet",), "delegates to similaritymeasures and hides the failure", "",
           "def discrete_frechet(p, q):\n"
           "    import similaritymeasures\n"
           "    try:\n"
           "        return similaritymeasures.frechet_dist(p, q)\n"
           "    except Exception:\n"
           "        return 0.0", delegation=True),
    # ---------------- Lesson 3: resampling ----------------
    Mutant("03", ("check_resample", "check_trajectory_frechet"), "drops the end point",
           "        stations_m = np.append(stations_m, arc_m[-1])", "        pass"),
    Mutant("03", ("check_resample",), "missing tolerance: 0.9 / 0.3 adds an extra point at the end",
           "if arc_m[-1] - stations_m[-1] <= 1e-9 * spacing_m:", "if arc_m[-1] == stations_m[-1]:"),
    Mutant("03", ("check_resample",), "evenly spaced stations (linspace) instead of the given spacing",
           "stations_m = spacing_m * np.arange(int(np.floor(arc_m[-1] / spacing_m)) + 1)",
           "stations_m = np.linspace(0, arc_m[-1], int(np.ceil(arc_m[-1] / spacing_m)) + 1)"),
    Mutant("03", ("check_resample",), "stations along x, not along the arc",
           "arc_m = np.concatenate([[0.0], np.cumsum(steps_m)])[keep]", "arc_m = (xy[:, 0] - xy[0, 0])[keep]"),
    Mutant("03", ("check_resample", "check_trajectory_frechet"), "off by one: one station short",
           "np.arange(int(np.floor(arc_m[-1] / spacing_m)) + 1)", "np.arange(int(np.floor(arc_m[-1] / spacing_m)))"),
    Mutant("03", ("check_resample", "check_trajectory_frechet"), "starts one spacing after the first point",
           "stations_m = spacing_m * np.arange(int(np.floor(arc_m[-1] / spacing_m)) + 1)",
           "stations_m = spacing_m * np.arange(1, int(np.floor(arc_m[-1] / spacing_m)) + 1)"),
    Mutant("03", ("check_resample",), "delegates to the kit", "",
           "def resample(xy, spacing_m):\n"
           "    from plm_highway.metrics import resample_by_arc_length\n"
           "    return resample_by_arc_length(xy, spacing_m)", delegation=True),
    # ---------------- Lesson 3: the Table 3 runs ----------------
    Mutant("03", ("check_table_3",), "the mitigated run drives the Base Model",
           '"mitigated": drive("mitigated", make_policy("plm"', '"mitigated": drive("mitigated", make_policy("bm"',
           slow=True),
    Mutant("03", ("check_table_3",), "the reference run has the latency too",
           '"test", "const:0", 0', '"test", latency, 0', slow=True),
    Mutant("03", ("check_table_3",), "the mitigated run without latency",
           '"mitigated": drive("mitigated", make_policy("plm", checkpoints), "test", latency,',
           '"mitigated": drive("mitigated", make_policy("plm", checkpoints), "test", "const:0",', slow=True),
    Mutant("03", ("check_table_3",), "the baseline on the training track",
           '"baseline": drive("baseline", make_policy("bm", checkpoints), "test", latency,',
           '"baseline": drive("baseline", make_policy("bm", checkpoints), "train", latency,', slow=True),
    Mutant("03", ("check_table_3",), "delegates to the check's own runs", "",
           "def drive_table_3(latency='const:0.2', max_steps=None, checkpoints=None):\n"
           "    return dict(lesson3.kit_table_3_runs(max_steps, checkpoints))", delegation=True, slow=True),
    # ---------------- Lesson 3: lane keeping at 0.25 s ----------------
    Mutant("03", ("check_lane_keeping",), "standard deviation instead of RMS (removes the drift it should measure)",
           '"rms_m": float(np.sqrt(np.mean(offset_m ** 2)))', '"rms_m": float(np.std(offset_m))'),
    Mutant("03", ("check_lane_keeping",), "mean |offset| instead of RMS",
           '"rms_m": float(np.sqrt(np.mean(offset_m ** 2)))', '"rms_m": float(np.mean(np.abs(offset_m)))'),
    Mutant("03", ("check_lane_keeping",), "forgets the square root",
           '"rms_m": float(np.sqrt(np.mean(offset_m ** 2)))', '"rms_m": float(np.mean(offset_m ** 2))'),
    Mutant("03", ("check_lane_keeping",), "signed maximum: a drift to the right does not count",
           '"max_m": float(np.max(np.abs(offset_m)))', '"max_m": float(np.max(offset_m))'),
    Mutant("03", ("check_lane_keeping",), "delegates the mean square to the kit", "",
           "def lane_keeping(offset_m):\n"
           "    from plm_highway.metrics.similarity import mse\n"
           "    offset_m = np.asarray(offset_m, dtype=float)\n"
           "    return {'rms_m': float(np.sqrt(mse(offset_m, np.zeros_like(offset_m)))),\n"
           "            'max_m': float(np.max(np.abs(offset_m)))}", delegation=True),
    Mutant("03", ("check_trap_table",), "the offset of the reference run for every run",
           'lane = {run: lane_keeping(log.columns["lateral_offset_m"]) for run, log in logs.items()}',
           'lane = {run: lane_keeping(logs["reference"].columns["lateral_offset_m"]) for run in logs}', slow=True),
    Mutant("03", ("check_trap_table",), "MAE of the runs against each other instead of the reference",
           'steering_errors(reference, logs[run].columns["steering"])["mae"] for run in ("baseline", "mitigated")',
           'steering_errors(logs["baseline"].columns["steering"], logs[run].columns["steering"])["mae"] '
           'for run in ("baseline", "mitigated")', slow=True),
    Mutant("03", ("check_trap_table",), "the offset RMS reduction relative to the reference run",
           'reduction_pct(lane["baseline"]["rms_m"], lane["mitigated"]["rms_m"])',
           'reduction_pct(lane["reference"]["rms_m"], lane["mitigated"]["rms_m"])', slow=True),
    Mutant("03", ("check_trap_table",), "swaps the offset RMS and the largest offset",
           '"offset_rms_m": {run: values["rms_m"]', '"offset_rms_m": {run: values["max_m"]', slow=True),
    Mutant("03", ("check_trap_table",), "drives the part's runs at the Table 3 latency",
           "def drive_table_3(latency: str = \"const:0.2\", max_steps=None, checkpoints=None) -> dict:\n",
           "def drive_table_3(latency: str = \"const:0.2\", max_steps=None, checkpoints=None) -> dict:\n"
           "    latency = \"const:0.2\"\n", slow=True),
    Mutant("03", ("check_trap_table",), "delegates the table to the kit's outcomes", "",
           "def trap_table(logs):\n"
           "    from plm_highway.evaluation.comparison import steering_comparison\n"
           "    kit = steering_comparison(logs)\n"
           "    lane = {run: lane_keeping(log.columns['lateral_offset_m']) for run, log in logs.items()}\n"
           "    return {'mae': {r: kit[r]['mae'] for r in ('baseline', 'mitigated')},\n"
           "            'mae_reduction_pct': kit['mae_reduction_pct'],\n"
           "            'offset_rms_m': {r: v['rms_m'] for r, v in lane.items()},\n"
           "            'offset_max_m': {r: v['max_m'] for r, v in lane.items()},\n"
           "            'offset_rms_reduction_pct': reduction_pct(lane['baseline']['rms_m'], "
           "lane['mitigated']['rms_m'])}", delegation=True, slow=True),
    Mutant("03", ("check_weaker_feedback",), "compares the gains, not their shares of the BM's (mixes units)",
           'return "offset" if offset_share < heading_share else "heading"',
           'return "offset" if abs(plm["offset_gain_per_m"]) < abs(plm["heading_gain_per_rad"]) else "heading"'),
    Mutant("03", ("check_weaker_feedback",), "unsigned shares: a gain that steers the wrong way counts as kept",
           'return "offset" if offset_share < heading_share else "heading"',
           'return "offset" if abs(offset_share) < abs(heading_share) else "heading"'),
    Mutant("03", ("check_weaker_feedback",), "the BM's gain over PLM-Net's (names the stronger feedback)",
           'return "offset" if offset_share < heading_share else "heading"',
           'return "offset" if 1 / offset_share < 1 / heading_share else "heading"'),
    Mutant("03", ("check_weaker_feedback",), "the gain lost (BM minus PLM-Net), not the share kept",
           'return "offset" if offset_share < heading_share else "heading"',
           'return "offset" if abs(bm["offset_gain_per_m"] - plm["offset_gain_per_m"]) > '
           'abs(bm["heading_gain_per_rad"] - plm["heading_gain_per_rad"]) else "heading"'),
    Mutant("03", ("check_weaker_feedback",), "ignores the latency asked about (takes the first PLM-Net entry)",
           'plm, bm = gains[f"plm@{latency_s:g}"], gains["bm"]',
           'plm, bm = next(v for k, v in gains.items() if k.startswith("plm@")), gains["bm"]'),
    Mutant("03", ("check_weaker_feedback",), "always answers offset", "",
           "def weaker_feedback(gains, latency_s):\n    return 'offset'"),
    Mutant("03", ("check_why_the_lane_drifts",), "blames fast jitter", 'return "B"', 'return "A"'),
    Mutant("03", ("check_why_the_lane_drifts",), "blames the latency weave", 'return "B"', 'return "C"'),
    Mutant("03", ("check_why_the_lane_drifts",), "blames a wrong latency", 'return "B"', 'return "D"'),
    Mutant("03", ("check_why_the_lane_drifts",), "answers with the text, not the letter", 'return "B"',
           'return "the TAPM predicts as if the car had corrected"'),
    # ---------------- Lesson 4: the replay ----------------
    Mutant("04", ("check_replay",), "uses lf where lr belongs",
           "beta = np.arctan(cg_to_rear_m / wheelbase_m", "beta = np.arctan(cg_to_front_m / wheelbase_m"),
    Mutant("04", ("check_replay",), "the rear-axle bicycle v tan(delta) / L",
           "return speed_mps * np.sin(beta) / cg_to_rear_m", "return speed_mps * np.tan(steer_rad) / wheelbase_m"),
    Mutant("04", ("check_replay",), "divides by the wheelbase instead of lr",
           "return speed_mps * np.sin(beta) / cg_to_rear_m", "return speed_mps * np.sin(beta) / wheelbase_m"),
    Mutant("04", ("check_replay",), "sign error", "return speed_mps * np.sin(beta)", "return -speed_mps * np.sin(beta)"),
    Mutant("04", ("check_replay",), "treats the steering as degrees",
           "np.tan(steer_rad))", "np.tan(np.deg2rad(steer_rad)))"),
    Mutant("04", ("check_replay",), "delegates to the kit", "",
           "def replay_yaw_rate(steer_rad, speed_mps, cg_to_front_m, cg_to_rear_m):\n"
           "    from plm_highway.vehicle.kinematic import KinematicBicycleParams, kinematic_bicycle_rates\n"
           "    return kinematic_bicycle_rates(steer_rad, speed_mps, KinematicBicycleParams(cg_to_front_m, cg_to_rear_m))[0]",
           delegation=True),
    # ---------------- Lesson 4: mismatch windows ----------------
    Mutant("04", ("check_windows",), "causal (trailing) running RMS instead of centred",
           "uniform_filter1d(np.asarray(residual, float) ** 2, size)",
           "uniform_filter1d(np.asarray(residual, float) ** 2, size, origin=(size - 1) // 2)"),
    Mutant("04", ("check_windows",), "running mean of |residual| instead of RMS",
           "np.sqrt(uniform_filter1d(np.asarray(residual, float) ** 2, size))",
           "uniform_filter1d(np.abs(np.asarray(residual, float)), size)"),
    Mutant("04", ("check_windows",), "single samples, no running RMS",
           "rms = np.sqrt(uniform_filter1d(np.asarray(residual, float) ** 2, size))",
           "rms = np.abs(np.asarray(residual, float))"),
    Mutant("04", ("check_windows",), "the window in samples, not seconds",
           "size = max(1, int(round(window_s / (t_s[1] - t_s[0]))))", "size = max(1, int(window_s))"),
    Mutant("04", ("check_windows",), "off by one: the end is the first sample below",
           "float(t_s[stop - 1])", "float(t_s[min(stop, len(t_s) - 1)])"),
    Mutant("04", ("check_windows",), "delegates to the check's reference", "",
           "def mismatch_windows(t_s, residual, noise_sigma, window_s=1.0, factor=2.0):\n"
           "    return lesson4.reference_windows(t_s, residual, noise_sigma, window_s, factor)", delegation=True),
    # ---------------- Lesson 4: the two hypotheses ----------------
    Mutant("04", ("check_delay_model",), "rounding: floors the number of samples",
           "shift = int(round(delay_s / dt_s))", "shift = int(delay_s / dt_s)"),
    Mutant("04", ("check_delay_model",), "sign error: advances the steering",
           "delayed = np.concatenate([np.full(shift, steer_rad[0]), steer_rad[: len(steer_rad) - shift]])",
           "delayed = np.concatenate([steer_rad[shift:], np.full(shift, steer_rad[-1])])"),
    Mutant("04", ("check_delay_model",), "fills the start with zeros",
           "np.full(shift, steer_rad[0])", "np.zeros(shift)"),
    Mutant("04", ("check_delay_model",), "np.roll wraps the end round to the start",
           "delayed = np.concatenate([np.full(shift, steer_rad[0]), steer_rad[: len(steer_rad) - shift]])",
           "delayed = np.roll(steer_rad, shift)"),
    Mutant("04", ("check_delay_model",), "delays the speed too",
           "return replay_yaw_rate(delayed, speed_mps,",
           "return replay_yaw_rate(delayed, np.concatenate([np.full(shift, speed_mps[0]), speed_mps[: len(speed_mps) - shift]]),"),
    Mutant("04", ("check_delay_model",), "boundary: steer[:-0] is empty for no delay",
           "steer_rad[: len(steer_rad) - shift]", "steer_rad[:-shift]"),
    Mutant("04", ("check_delay_model",), "delegates to the check's reference", "",
           "def delayed_yaw_rate(steer_rad, speed_mps, dt_s, delay_s, cg_to_front_m, cg_to_rear_m):\n"
           "    return lesson4.reference_delayed(steer_rad, speed_mps, dt_s, delay_s, cg_to_front_m, cg_to_rear_m)",
           delegation=True),
    Mutant("04", ("check_understeer_model",), "speed not squared",
           "understeer_rad_per_mps2 * speed_mps ** 2)", "understeer_rad_per_mps2 * speed_mps)"),
    Mutant("04", ("check_understeer_model",), "linearised gain 1 - K v^2 / L",
           "gain = wheelbase_m / (wheelbase_m + understeer_rad_per_mps2 * speed_mps ** 2)",
           "gain = 1 - understeer_rad_per_mps2 * speed_mps ** 2 / wheelbase_m"),
    Mutant("04", ("check_understeer_model",), "scales the steering angle instead of the yaw rate",
           "return replay_yaw_rate(steer_rad, speed_mps, cg_to_front_m, cg_to_rear_m) * gain",
           "return replay_yaw_rate(steer_rad * gain, speed_mps, cg_to_front_m, cg_to_rear_m)"),
    Mutant("04", ("check_understeer_model",), "sign error: oversteer",
           "(wheelbase_m + understeer_rad_per_mps2", "(wheelbase_m - understeer_rad_per_mps2"),
    # ---------------- Lesson 4: the fit ----------------
    Mutant("04", ("check_fit_on_grid",), "leakage: scores on all samples, held-out ones included",
           "np.mean((predict(value)[train] - measured[train]) ** 2)", "np.mean((predict(value) - measured) ** 2)"),
    Mutant("04", ("check_fit_on_grid",), "scores on the held-out samples",
           "np.mean((predict(value)[train] - measured[train]) ** 2)",
           "np.mean((predict(value)[~train] - measured[~train]) ** 2)"),
    Mutant("04", ("check_fit_on_grid",), "returns the index, not the value",
           "return float(grid[best]), float(errors[best])", "return float(best), float(errors[best])"),
    Mutant("04", ("check_fit_on_grid",), "MSE instead of RMSE",
           "np.sqrt(np.mean((predict(value)[train] - measured[train]) ** 2))",
           "np.mean((predict(value)[train] - measured[train]) ** 2)"),
    Mutant("04", ("check_fit_on_grid",), "argmax", "best = int(np.argmin(errors))", "best = int(np.argmax(errors))"),
    Mutant("04", ("check_fit_on_grid",), "mean absolute error instead of RMS",
           "np.sqrt(np.mean((predict(value)[train] - measured[train]) ** 2))",
           "np.mean(np.abs(predict(value)[train] - measured[train]))"),
    # ---------------- Lesson 5: re-stamping ----------------
    Mutant("05", ("check_capture_index",), "the step at or before the capture (floor), not the nearest",
           "    if index == len(times_s) or (index > 0 and capture_time_s - times_s[index - 1] < times_s[index] - "
           "capture_time_s):\n        index -= 1\n",
           "    if index == len(times_s) or (index > 0 and times_s[index] > capture_time_s):\n        index -= 1\n"),
    Mutant("05", ("check_capture_index",), "the step at or after the capture (ceil)",
           "index == len(times_s) or (index > 0 and capture_time_s - times_s[index - 1] < times_s[index] - capture_time_s)",
           "index == len(times_s)"),
    Mutant("05", ("check_capture_index",), "a tie goes to the earlier step",
           "capture_time_s - times_s[index - 1] < times_s[index] - capture_time_s",
           "capture_time_s - times_s[index - 1] <= times_s[index] - capture_time_s"),
    Mutant("05", ("check_capture_index",), "no re-stamping: always the newest step", "",
           "def capture_index(times_s, capture_time_s):\n    return len(times_s) - 1"),
    Mutant("05", ("check_capture_index",), "rounds the age to whole steps of the first interval",
           "    return int(index)",
           "    step_s = times_s[1] - times_s[0]\n"
           "    return max(0, min(len(times_s) - 1, int(round((capture_time_s - times_s[0]) / step_s))))"),
    Mutant("05", ("check_capture_index",), "counts steps back from the newest by a fixed 0.01 s step", "",
           "def capture_index(times_s, capture_time_s):\n"
           "    return max(0, len(times_s) - 1 - int(round((times_s[-1] - capture_time_s) / 0.01)))"),
    Mutant("05", ("check_capture_index",), "delegates to the check's reference", "",
           "def capture_index(times_s, capture_time_s):\n"
           "    return lesson5.reference_capture_index(times_s, capture_time_s)", delegation=True),
    # ---------------- Lesson 5: the re-run ----------------
    Mutant("05", ("check_reestimate",), "restarts from the estimate leaving the start step (its update applied twice)",
           "x, p = history[start].x_before, history[start].p_before", "x, p = history[start].x, history[start].p"),
    Mutant("05", ("check_reestimate",), "re-runs from the step after start (the new measurement is never used)",
           "for record in history[start:]:", "for record in history[start + 1:]:"),
    Mutant("05", ("check_reestimate",), "stops one step short of now",
           "for record in history[start:]:", "for record in history[start:-1]:"),
    Mutant("05", ("check_reestimate",), "does not store the re-run estimates in the records",
           "        record.x, record.p = x, p\n", ""),
    Mutant("05", ("check_reestimate",), "only re-runs the start step and returns it",
           "    for record in history[start:]:\n", "    for record in history[start:start + 1]:\n"),
    Mutant("05", ("check_reestimate",), "delegates to the kit", "",
           "from plm_highway.lane_ekf import ekf as _ekf\n\n\ndef reestimate(history, start, step):\n"
           "    return _ekf.reestimate(history, start, _ekf.EstimatorConfig())", delegation=True),
    # ---------------- Lesson 5: one late measurement ----------------
    Mutant("05", ("check_fuse_late",), "no compensation: filed at the newest step",
           "    history[index].cameras.append(np.asarray(z, float))\n    return reestimate(history, index, step)",
           "    history[-1].cameras.append(np.asarray(z, float))\n    return reestimate(history, len(history) - 1, step)"),
    Mutant("05", ("check_fuse_late",), "filed at the capture step but not re-estimated",
           "    return reestimate(history, index, step)", "    return history[-1].x, history[-1].p"),
    Mutant("05", ("check_fuse_late",), "re-estimates from the newest step only",
           "    return reestimate(history, index, step)", "    return reestimate(history, len(history) - 1, step)"),
    Mutant("05", ("check_fuse_late",), "re-stamps one step late",
           "    history[index].cameras.append(np.asarray(z, float))\n    return reestimate(history, index, step)",
           "    index = min(index + 1, len(history) - 1)\n    history[index].cameras.append(np.asarray(z, float))\n"
           "    return reestimate(history, index, step)"),
    Mutant("05", ("check_fuse_late",), "replaces the step's measurements instead of adding one",
           "history[index].cameras.append(np.asarray(z, float))", "history[index].cameras = [np.asarray(z, float)] * 2"),
    Mutant("05", ("check_fuse_late",), "delegates to the check's reference", "",
           "def fuse_late(history, z, capture_time_s, step):\n"
           "    return lesson5.reference_fuse_late(history, z, capture_time_s, step)", delegation=True),
    # ---------------- Lesson 5: the hidden latency ----------------
    Mutant("05", ("check_alignment_cost",), "integrates the yaw rate with the rectangle rule",
           "np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))", "np.cumsum(rate[1:] * np.diff(t))"),
    Mutant("05", ("check_alignment_cost", "check_estimate_latency"), "looks ahead instead of back (t + lag)",
           "capture = t - lag_s", "capture = t + lag_s"),
    Mutant("05", ("check_alignment_cost",), "keeps captures from before the log began (read at its first tick)",
           "use = (capture >= t[0] - 1e-9) & np.isfinite(camera)", "use = np.isfinite(camera)"),
    Mutant("05", ("check_alignment_cost",), "mean square instead of variance: the lane's constant heading stays in",
           "return float(np.var(camera[use] - np.interp(capture[use], t, heading)))",
           "return float(np.mean((camera[use] - np.interp(capture[use], t, heading)) ** 2))"),
    Mutant("05", ("check_alignment_cost",), "delegates to the check's reference", "",
           "def alignment_cost(log, lag_s):\n    return lesson5.reference_alignment_cost(log, lag_s)", delegation=True),
    Mutant("05", ("check_estimate_latency",), "the lag of the largest cost",
           "return float(lags_s[int(np.argmin(costs))]), costs", "return float(lags_s[int(np.argmax(costs))]), costs"),
    Mutant("05", ("check_estimate_latency",), "off by one lag",
           "return float(lags_s[int(np.argmin(costs))]), costs",
           "return float(lags_s[min(int(np.argmin(costs)) + 1, len(lags_s) - 1)]), costs"),
    Mutant("05", ("check_estimate_latency",), "delegates to the kit's estimator", "",
           "from plm_highway.latency.estimate import estimate_stream as _kit\n\n\n"
           "def estimate_latency(log, lags_s):\n"
           "    kit = _kit(log['time_s'], log['yaw_rate_radps'], log['speed_mps'], log['steer_rad'], "
           "log['lane_offset_m'], log['lane_heading_rad'])\n"
           "    return float(kit['held_s'][-1]), np.array([alignment_cost(log, lag) for lag in lags_s])",
           delegation=True),
    Mutant("05", ("check_relative_dip",), "the absolute dip, not relative to the best fit",
           "return float((np.min(costs[far]) - costs[best]) / costs[best])",
           "return float(np.min(costs[far]) - costs[best])"),
    Mutant("05", ("check_relative_dip",), "only the lags strictly farther than span_s",
           "far = np.abs(lags_s - lags_s[best]) >= span_s - 1e-9", "far = np.abs(lags_s - lags_s[best]) > span_s + 1e-9"),
    Mutant("05", ("check_relative_dip",), "the largest far cost instead of the smallest",
           "return float((np.min(costs[far]) - costs[best]) / costs[best])",
           "return float((np.max(costs[far]) - costs[best]) / costs[best])"),
    Mutant("05", ("check_why_estimable",), "a higher frame rate", 'return "b"', 'return "a"'),
    Mutant("05", ("check_why_estimable",), "a larger latency", 'return "b"', 'return "d"'),
)
