"""Every file the project writes goes through here.

- :mod:`plm_highway.io.outputs`: the safe-output mechanism (targets checked, outputs staged and
  published atomically, nothing replaced that plm-highway did not write);
- :mod:`plm_highway.io.formats`: strict JSON, CSV tables, figures, the recorded command line.
"""

from plm_highway.io.formats import (
    BENCH_RESULT,
    FIGURE,
    command_line,
    format_cell,
    json_safe,
    json_text,
    pyplot,
    save_figure,
    save_figure_into,
    write_csv,
    write_csv_into,
    write_figure_and_numbers,
    write_json,
    write_text,
)
from plm_highway.io.outputs import (
    JSON_MARKER_KEY,
    MARKER_NAME,
    OutputKind,
    check_target,
    directory_kind,
    file_kind,
    remove_stale_staging,
    write_output,
    write_outputs,
)

__all__ = [
    "BENCH_RESULT",
    "FIGURE",
    "JSON_MARKER_KEY",
    "MARKER_NAME",
    "OutputKind",
    "check_target",
    "command_line",
    "directory_kind",
    "file_kind",
    "format_cell",
    "json_safe",
    "json_text",
    "pyplot",
    "remove_stale_staging",
    "save_figure",
    "save_figure_into",
    "write_csv",
    "write_csv_into",
    "write_figure_and_numbers",
    "write_json",
    "write_output",
    "write_outputs",
    "write_text",
]
