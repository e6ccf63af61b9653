"""Every file the project writes goes through here.

- :mod:`plm_highway.io.outputs`: the safe-output mechanism (targets checked, outputs staged and
  published atomically, nothing replaced that plm-highway did not write);
- :mod:`plm_highway.io.manifest`: the list of files a directory output holds of plm-highway's own;
- :mod:`plm_highway.io.bounded`: reading JSON, YAML and CSV with every size bounded (bytes, depth,
  values after alias expansion, long integers, duplicate keys);
- :mod:`plm_highway.io.formats`: strict JSON, CSV tables, figures, the recorded command line.
"""

from plm_highway.io.bounded import (
    JsonLimits,
    check_csv_columns,
    decode_utf8,
    load_json,
    load_yaml,
    parse_float_text,
    parse_int_text,
    parse_json,
    parse_yaml,
    read_bounded,
    refuse_non_ascii_digits,
    require_int,
)
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
    unique_file_names,
    write_csv,
    write_csv_into,
    write_figure_and_numbers,
    write_json,
    write_text,
)
from plm_highway.io.manifest import MARKER_NAME
from plm_highway.io.outputs import (
    JSON_MARKER_KEY,
    OutputKind,
    check_target,
    directory_kind,
    file_kind,
    protected_inputs,
    remove_stale_staging,
    write_output,
    write_outputs,
)

__all__ = [
    "BENCH_RESULT",
    "FIGURE",
    "JSON_MARKER_KEY",
    "MARKER_NAME",
    "JsonLimits",
    "OutputKind",
    "check_csv_columns",
    "check_target",
    "command_line",
    "decode_utf8",
    "directory_kind",
    "file_kind",
    "format_cell",
    "json_safe",
    "json_text",
    "load_json",
    "load_yaml",
    "parse_float_text",
    "parse_int_text",
    "parse_json",
    "parse_yaml",
    "protected_inputs",
    "pyplot",
    "read_bounded",
    "refuse_non_ascii_digits",
    "require_int",
    "remove_stale_staging",
    "save_figure",
    "save_figure_into",
    "unique_file_names",
    "write_csv",
    "write_csv_into",
    "write_figure_and_numbers",
    "write_json",
    "write_output",
    "write_outputs",
    "write_text",
]
