"""The files: measurement CSVs, model-config TOML, run directories as data, in the order they
build on each other: a record as the estimators take it (`experiment`), a user's files read
(`files`), measurement CSVs (`measurement_csv`), model configs read and checked (`config`) and
written (`config_text`), run directories and estimates (`runs`). This front holds the names the
rest of the package and users take from `testbed.data`.

Readers validate everything a user can get wrong and raise `InputError` with a one-line message
naming the file and the field; writers go through `atomic_write_text`.
"""

from testbed.data.experiment import (
    Experiment,
    MAX_DATA,
    MAX_GAP,
    MIN_ROWS,
    check_excited,
    check_experiment,
    median,
    split,
    stretch_name,
    stretches,
)
from testbed.data.files import MAX_NAME, check_name, read_json, read_toml
from testbed.data.measurement_csv import (
    CLOCK_DIVISIONS,
    CLOCK_POINTS,
    CSV_COLUMNS,
    MAX_SAMPLES,
    SLOWER,
    WRAPPING,
    clock,
    csv_text,
    read_csv,
    stale,
    write_csv,
)
from testbed.data.config import (
    CONFIG_SENSOR_KEYS,
    MAX_CONSTANT,
    MIN_NOISE_STD,
    ModelConfig,
    check_config,
    check_free,
    check_noise_std,
    check_per_record,
    number,
    parse_config,
    parse_sensor,
    read_config,
)
from testbed.data.config_text import config_text, sensor_table, toml_value, write_config
from testbed.data.runs import load_data, read_estimates, run_csvs

__all__ = [
    "CLOCK_DIVISIONS",
    "CLOCK_POINTS",
    "CONFIG_SENSOR_KEYS",
    "CSV_COLUMNS",
    "Experiment",
    "MAX_CONSTANT",
    "MAX_DATA",
    "MAX_GAP",
    "MAX_NAME",
    "MAX_SAMPLES",
    "MIN_NOISE_STD",
    "MIN_ROWS",
    "ModelConfig",
    "SLOWER",
    "WRAPPING",
    "check_config",
    "check_excited",
    "check_experiment",
    "check_free",
    "check_name",
    "check_noise_std",
    "check_per_record",
    "clock",
    "config_text",
    "csv_text",
    "load_data",
    "median",
    "number",
    "parse_config",
    "parse_sensor",
    "read_config",
    "read_csv",
    "read_estimates",
    "read_json",
    "read_toml",
    "run_csvs",
    "sensor_table",
    "split",
    "stale",
    "stretch_name",
    "stretches",
    "toml_value",
    "write_config",
    "write_csv",
]
