"""Refusals of the safe-output mechanism name their culprit: another plm-highway writing the same target, and the
output a full disk interrupted."""

from __future__ import annotations

import errno
import subprocess
import sys
from pathlib import Path

import pytest

from plm_highway.cli import describe_os_error
from plm_highway.errors import OutputRefused
from plm_highway.io import check_target, file_kind, write_json, write_output

REPO_ROOT = Path(__file__).resolve().parent.parent
KIND = file_kind("message-test", "a message test JSON file")


def write_in_another_process(path: Path) -> None:
    code = ("import sys; from plm_highway.io import file_kind, write_json; "
            "write_json(sys.argv[1], {'x': 1}, file_kind('message-test', 'a message test JSON file'))")
    subprocess.run([sys.executable, "-c", code, str(path)], check=True, env={"PYTHONPATH": str(REPO_ROOT)})


def test_a_target_another_plm_highway_wrote_meanwhile_names_it_not_overwrite(tmp_path):
    target = tmp_path / "result.json"
    check_target(target, KIND)  # this run starts: nothing there
    write_in_another_process(target)  # another plm-highway publishes first
    with pytest.raises(OutputRefused) as refused:
        write_json(target, {"x": 2}, KIND)
    message = str(refused.value)
    assert "another plm-highway is writing" in message and str(target) in message and "--overwrite" not in message
    assert target.read_text().count('"x": 1') == 1  # the winner's output stands


def test_an_earlier_output_is_still_refused_with_the_overwrite_advice(tmp_path):
    target = tmp_path / "result.json"
    write_in_another_process(target)  # there before this run started
    with pytest.raises(OutputRefused, match="pass --overwrite"):
        check_target(target, KIND)


def test_a_live_writer_of_a_new_target_is_named_at_once(tmp_path):
    target = tmp_path / "out"
    kind = file_kind("message-test", "a message test JSON file")
    with write_output(target, kind) as staged:  # this process holds the staging directory, locked
        staged.write_text("{}")
        code = ("import sys; from plm_highway.io import check_target, file_kind; "
                "check_target(sys.argv[1], file_kind('message-test', 'a message test JSON file'))")
        done = subprocess.run([sys.executable, "-c", code, str(target)], capture_output=True, text=True,
                              env={"PYTHONPATH": str(REPO_ROOT)})
    assert done.returncode != 0 and "another plm-highway is writing" in done.stderr


@pytest.mark.parametrize("number", [errno.ENOSPC, errno.EDQUOT])
def test_a_full_disk_names_the_output_being_written(tmp_path, number):
    target = tmp_path / "big.json"
    with pytest.raises(OSError) as raised:
        with write_output(target, KIND):
            raise OSError(number, "No space left on device")  # what a write or close says, with no path
    line = describe_os_error(raised.value)
    assert str(target) in line and "No space left on device" in line and "nothing was published" in line
    assert not target.exists() and list(tmp_path.iterdir()) == []
