"""Headless jobs: each command of the command line as one library function.

A job reads its inputs (run directories, measurement CSVs, model configs, estimates), checks
every output it will write before doing any work (none may be an input or another output),
does the work, and writes its outputs atomically: all of them or none. It returns what it
computed; it prints nothing. Parameters are named as in Python (`max_iter`); `testbed.cli`
maps them to its flags.

One module per command: `identify` (with the screened fit), `analyze`, `check`, `validate`;
`common` holds what they share. The other commands' jobs are their layers' own functions:
`simulation.runs.simulate`, `simulation.analytic.analytic_config_text`,
`captive.config.captive_config_text` (with `presentation.captive_report`),
`presentation.design_report.write_design`, `study.campaign.reproduce`,
`presentation.report.replay`.
"""

__all__: list[str] = []
