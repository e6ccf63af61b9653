"""Training BM and TAPM end to end on small synthetic datasets (plm_highway.training)."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shlex

import numpy as np
import pytest
import torch

from plm_highway import cli
from plm_highway.data.dataset import read_dataset
from plm_highway.models.base_model import BaseModel
from plm_highway.models.checkpoints import load_base_model, load_plm_net
from plm_highway.models.tapm import TAPM, TAPMConfig
from plm_highway.training.samples import bm_rows, split_train_val, tapm_rows
from plm_highway.training.synthetic import make_synthetic_dataset
from plm_highway.training.train import (
    TrainConfig,
    deterministic,
    fit,
    freeze,
    tapm_loss,
    train_base_model,
    train_tapm,
)

TINY = TrainConfig(epochs=1, max_samples=96, show_progress=False)


@pytest.fixture(autouse=True, scope="module")
def threads_per_worker():
    """Share the cores among pytest-xdist workers: oversubscribed torch threads spin and crawl."""
    previous = torch.get_num_threads()
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    torch.set_num_threads(max(1, len(os.sched_getaffinity(0)) // workers))
    yield
    torch.set_num_threads(previous)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    return make_synthetic_dataset(
        tmp_path_factory.mktemp("data") / "synthetic", n_episodes=6, steps_per_episode=30
    )


@pytest.fixture(scope="module")
def trained_bm_dir(data_dir, tmp_path_factory):
    out_dir = tmp_path_factory.mktemp("bm")
    train_base_model(data_dir, out_dir, config=TINY)
    return out_dir


def test_train_bm_and_tapm_through_the_cli_and_reload_them(data_dir, tmp_path, capsys):
    common = [
        "--data",
        str(data_dir),
        "--epochs",
        "2",
        "--max-samples",
        "128",
        "--seed",
        "3",
        "--quiet",
        "--threads",
        str(torch.get_num_threads()),
    ]
    assert cli.main(["train", "bm", "--out", str(tmp_path / "bm"), *common]) == 0
    assert (
        cli.main(["train", "tapm", "--out", str(tmp_path / "tapm"), "--bm", str(tmp_path / "bm"), *common])
        == 0
    )
    printed = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert all(np.isfinite(summary["best_val_loss"]) for summary in printed)

    plm_net = load_plm_net(tmp_path / "bm", tmp_path / "tapm")
    frames = torch.from_numpy(np.array(read_dataset(data_dir).frames[:3]))
    with torch.inference_mode():
        output = plm_net(frames, torch.full((3,), 16.7), torch.tensor([0.0, 0.2, 0.3]))
    assert output.a_ref.shape == (3, 6) and torch.all(output.steering.abs() <= 1)

    tapm_document = json.loads((tmp_path / "tapm" / "model.json").read_text())
    assert tapm_document["preset"] == "default" and tapm_document["image_size_px"] == [66, 200]
    assert tapm_document["delta_grid_s"] == [0.15, 0.2, 0.25, 0.3, 0.35]
    training = tapm_document["training"]
    assert training["epochs_run"] == 2 and training["data_seed"] == 0 and training["config"]["seed"] == 3
    assert training["data_manifest"].endswith("manifest.json")
    # the command exactly as typed, ready to paste back into a shell
    assert training["command"] == shlex.join(["plm-highway", "train", "tapm", "--out", str(tmp_path / "tapm"),
                                              "--bm", str(tmp_path / "bm"), *common])
    assert (tmp_path / "bm" / "steering_balance.png").is_file()


def test_same_seed_gives_bit_identical_weights_and_another_seed_does_not(data_dir, tmp_path):
    def trained_state(name, seed):
        train_base_model(data_dir, tmp_path / name, config=TrainConfig(**{**TINY.__dict__, "seed": seed}))
        return load_base_model(tmp_path / name).state_dict()

    first, again, other = trained_state("a", 0), trained_state("b", 0), trained_state("c", 1)
    assert all(torch.equal(first[key], again[key]) for key in first)
    assert not all(torch.equal(first[key], other[key]) for key in first)


def test_bm_stays_frozen_and_in_eval_mode_while_the_tapm_trains(data_dir, trained_bm_dir):
    dataset = read_dataset(data_dir)
    bm = freeze(load_base_model(trained_bm_dir))
    before = {key: value.clone() for key, value in bm.state_dict().items()}
    bm_modes = []
    bm.register_forward_pre_hook(lambda module, _: bm_modes.append(module.training))
    bm.mlp[2].register_forward_pre_hook(lambda module, _: bm_modes.append(module.training))  # a dropout layer
    train_rows, val_rows = split_train_val(tapm_rows(dataset, (0.15, 0.25)), 0.2, np.random.default_rng(0))
    tapm = TAPM(TAPMConfig(image_feature_dim=bm.image_feature_dim, delta_grid_s=(0.15, 0.25)))
    tapm_modes = []
    tapm.register_forward_pre_hook(lambda module, _: tapm_modes.append(module.training))
    tapm_before = tapm.heads_out.weight.detach().clone()

    fit(tapm, tapm_loss(tapm, bm), dataset.frames, train_rows, val_rows, TINY, "TAPM")

    assert all(torch.equal(before[key], value) for key, value in bm.state_dict().items())
    assert bm_modes and not any(bm_modes)
    assert True in tapm_modes  # the TAPM itself did train with dropout on
    assert not torch.equal(tapm_before, tapm.heads_out.weight)


def test_early_stopping_after_three_epochs_without_improvement(data_dir):
    dataset = read_dataset(data_dir)
    train_rows, val_rows = split_train_val(bm_rows(dataset), 0.2, np.random.default_rng(0))
    train_rows, val_rows = train_rows.subset(np.arange(32)), val_rows.subset(np.arange(32))
    config = TrainConfig(epochs=10, learning_rate=0.0, show_progress=False)  # the val loss never improves
    with deterministic(0):
        bm = BaseModel()
        result = fit(
            bm,
            lambda batch: torch.nn.functional.mse_loss(
                bm(batch.frames, batch.speed_mps), batch.targets[:, 0]
            ),
            dataset.frames,
            train_rows,
            val_rows,
            config,
            "BM",
        )
    assert (result.best_epoch, result.epochs_run, result.stopped_early) == (1, 4, True)
    assert len(set(result.val_loss_history)) == 1


def test_train_bm_rejects_a_dataset_from_another_camera(data_dir, tmp_path, capsys):
    code = cli.main(
        ["train", "bm", "--data", str(data_dir), "--out", str(tmp_path), "--preset", "paper", "--quiet"]
    )
    assert code == cli.EXIT_BAD_INPUT
    assert "dataset frames are 66x200 px but preset 'paper' expects 160x160 px" in capsys.readouterr().err


def test_train_tapm_checks_the_bm_preset_when_given(data_dir, trained_bm_dir, tmp_path, capsys):
    code = cli.main(
        [
            "train",
            "tapm",
            "--data",
            str(data_dir),
            "--out",
            str(tmp_path),
            "--bm",
            str(trained_bm_dir),
            "--preset",
            "paper",
            "--quiet",
        ]
    )
    assert code == cli.EXIT_BAD_INPUT
    assert "trained with preset 'default'" in capsys.readouterr().err


def test_train_reports_a_missing_dataset(tmp_path, capsys):
    assert cli.main(["train", "bm", "--data", str(tmp_path / "none"), "--out", str(tmp_path), "--quiet"]) == 2
    assert "no dataset manifest" in capsys.readouterr().err


def test_delta_grid_option_is_parsed_and_checked():
    from plm_highway.training.train import parse_delta_grid

    assert parse_delta_grid("0.1, 0.2,0.3") == (0.1, 0.2, 0.3)
    with pytest.raises(ValueError, match="--delta-grid"):
        parse_delta_grid("0.1,fast")


# -- bad arguments and unusable datasets: exit 2 before training, nothing written ----------------------


def run_train(command: str, data_dir, out, extra: list[str], bm_dir=None) -> int:
    args = ["train", command, "--data", str(data_dir), "--out", str(out), "--quiet", "--threads", "1"]
    if command == "tapm":
        args += ["--bm", str(bm_dir)]
    return cli.main(args + extra)


# One line per bad training argument: (command, arguments, message).
BAD_TRAIN_ARGUMENTS = [
    pytest.param("bm", ["--epochs", "0"], r"--epochs: must lie in \[1, 1000\], got 0", id="epochs-0"),
    pytest.param("bm", ["--epochs", "-2"], r"--epochs: must lie in \[1, 1000\], got -2", id="epochs-negative"),
    pytest.param("bm", ["--epochs", "100000"], r"--epochs: must lie in \[1, 1000\], got 100000", id="epochs-huge"),
    pytest.param("bm", ["--max-samples", "0"], r"--max-samples: must lie in \[2, 1000000000\], got 0",
                 id="max-samples-0"),
    pytest.param("bm", ["--max-samples", "1"], r"--max-samples: must lie in \[2, 1000000000\], got 1",
                 id="max-samples-1"),
    pytest.param("bm", ["--balance-max-per-bin", "-5"], r"--balance-max-per-bin: must be 0 \(off\) or >= 1, got -5",
                 id="balance-negative"),
    pytest.param("bm", ["--balance-max-per-bin", "10000000000"], r"--balance-max-per-bin: must lie in",
                 id="balance-huge"),
    pytest.param("bm", ["--threads", "0"], r"--threads: must lie in \[1, \d+\], got 0", id="threads-0"),
    pytest.param("bm", ["--threads", "100000"], r"--threads: must lie in \[1, \d+\], got 100000", id="threads-huge"),
    pytest.param("bm", ["--seed", "-1"], r"--seed: must lie in \[0, 9223372036854775807\], got -1", id="seed"),
    pytest.param("bm", ["--label-lead-s=-0.1"], r"--label-lead-s: must be a finite number in \[0, 2\], got -0.1",
                 id="lead-negative"),
    pytest.param("tapm", ["--label-lead-s", "nan"], r"--label-lead-s: must be a finite number in \[0, 2\], got nan",
                 id="lead-nan"),
    pytest.param("bm", ["--label-lead-s", "5"], r"--label-lead-s: must be a finite number in \[0, 2\], got 5.0",
                 id="lead-long"),
    pytest.param("tapm", ["--delta-grid", ""], r"--delta-grid: expected at least one latency", id="grid-empty"),
    pytest.param("tapm", ["--delta-grid", ",,"], r"--delta-grid: expected at least one latency", id="grid-commas"),
    pytest.param("tapm", ["--delta-grid", "0.15,abc"], r"--delta-grid: expected comma-separated seconds",
                 id="grid-word"),
    pytest.param("tapm", ["--delta-grid", "nan"], r"--delta-grid: latencies must be finite numbers in \(0, 10\] s, "
                 r"got nan", id="grid-nan"),
    pytest.param("tapm", ["--delta-grid", "0.2,inf"], r"--delta-grid: .*got inf", id="grid-inf"),
    pytest.param("tapm", ["--delta-grid", "0"], r"--delta-grid: .*got 0.0", id="grid-zero"),
    pytest.param("tapm", ["--delta-grid=-0.1,0.2"], r"--delta-grid: .*got -0.1", id="grid-negative"),
    pytest.param("tapm", ["--delta-grid", "0.2,0.15"], r"--delta-grid: latencies must be strictly increasing",
                 id="grid-decreasing"),
    pytest.param("tapm", ["--delta-grid", "0.2,0.2"], r"--delta-grid: latencies must be strictly increasing",
                 id="grid-repeated"),
    pytest.param("tapm", ["--delta-grid", "20"], r"--delta-grid: .*\(0, 10\] s, got 20.0", id="grid-late"),
    pytest.param("tapm", ["--delta-grid", ",".join(str(0.01 * (i + 1)) for i in range(33))],
                 r"--delta-grid: expected 1 to 32 latencies, got 33", id="grid-33"),
]


@pytest.mark.parametrize(("command", "arguments", "message"), BAD_TRAIN_ARGUMENTS)
def test_bad_training_arguments_exit_2_and_write_nothing(data_dir, trained_bm_dir, tmp_path, capsys, command,
                                                         arguments, message):
    out = tmp_path / "out"
    code = run_train(command, data_dir, out, arguments, trained_bm_dir)
    err = capsys.readouterr().err
    assert code == cli.EXIT_BAD_INPUT, err
    assert re.search(message, err), err
    assert "Traceback" not in err and not out.exists()


def test_a_bm_and_tapm_trained_with_one_label_lead_record_it_and_load_as_plm_net(data_dir, tmp_path):
    aligned = dataclasses.replace(TINY, label_lead_s=0.1)
    bm_description = train_base_model(data_dir, tmp_path / "bm", config=aligned)
    tapm_description = train_tapm(data_dir, tmp_path / "tapm", tmp_path / "bm", config=aligned)
    assert bm_description["training"]["config"]["label_lead_s"] == 0.1
    assert tapm_description["training"]["config"]["label_lead_s"] == 0.1
    assert load_plm_net(tmp_path / "bm", tmp_path / "tapm") is not None


def test_a_tapm_refuses_a_label_lead_other_than_its_bms(data_dir, trained_bm_dir, tmp_path, capsys):
    # The fixture BM was trained without label alignment (lead 0 s).
    out = tmp_path / "tapm"
    code = run_train("tapm", data_dir, out, ["--label-lead-s", "0.1"], trained_bm_dir)
    err = capsys.readouterr().err
    assert code == cli.EXIT_BAD_INPUT, err
    assert "--label-lead-s 0.1: the BM at" in err and "label lead of 0 s" in err, err
    assert "Traceback" not in err and not out.exists()


def short_episodes_dataset(path):
    """Episodes of 0.2 s: no row has a label 0.35 s ahead."""
    return make_synthetic_dataset(path, n_episodes=30, steps_per_episode=5)


# One line per dataset that training cannot use: (dataset factory, command, message).
UNUSABLE_DATASETS = [
    pytest.param(short_episodes_dataset, "tapm", r"dataset .*: no usable rows to train on", id="no-future-labels"),
    pytest.param(lambda path: make_synthetic_dataset(path, n_episodes=1, steps_per_episode=30), "bm",
                 r"dataset .*: cannot split 30 rows into train and validation: they form one block",
                 id="one-block"),
    pytest.param(lambda path: make_synthetic_dataset(path, n_episodes=1, steps_per_episode=30), "tapm",
                 r"dataset .* \(rows with a future label 0.35 s ahead\): cannot split 23 rows", id="one-block-tapm"),
]


@pytest.mark.parametrize(("factory", "command", "message"), UNUSABLE_DATASETS)
def test_unusable_datasets_are_refused_before_training_and_leave_nothing(trained_bm_dir, tmp_path, capsys, factory,
                                                                         command, message):
    data = factory(tmp_path / "data")
    out = tmp_path / "out"
    code = run_train(command, data, out, [], trained_bm_dir)
    err = capsys.readouterr().err
    assert code == cli.EXIT_BAD_INPUT, err
    assert re.search(message, err), err
    assert not out.exists()  # in particular no steering_balance.png


def test_train_config_defaults_are_the_command_line_defaults():
    argv = ["train", "bm", "--data", "d", "--out", "o"]
    args = cli.build_parser(argv).parse_args(argv)
    assert (args.epochs, args.seed, args.balance_max_per_bin) == (
        TrainConfig.epochs, TrainConfig.seed, TrainConfig.balance_max_per_bin)


@pytest.mark.parametrize(("flag", "quiet"), [("--quiet", True), ("--no-progress", True), (None, False)])
def test_train_takes_no_progress_as_the_other_commands_spell_it(flag, quiet):
    argv = ["train", "bm", "--data", "ds", "--out", "out", *([flag] if flag else [])]
    assert cli.build_parser(argv).parse_args(argv).quiet is quiet
