"""The LightningCLI behind ``python train.py`` (and ``wtml pipeline``).

The config names the LightningModule (``model.class_path``) and the LightningDataModule
(``data.class_path``). Logs go to CSV files under ``runs/`` unless the config says otherwise;
the progress bar shows only on a terminal and never under CI (``CI`` set).
"""

from __future__ import annotations

import os
import sys

from lightning.pytorch.cli import LightningCLI


def cli_main(args: list[str] | None = None, run: bool = True) -> LightningCLI:
    """Run LightningCLI with wtml's trainer defaults; ``args`` as on the command line."""
    trainer_defaults = {
        "logger": {"class_path": "lightning.pytorch.loggers.CSVLogger",
                   "init_args": {"save_dir": "runs"}},
        "enable_progress_bar": sys.stderr.isatty() and not os.environ.get("CI"),
        "enable_model_summary": False,
    }
    if args is None:
        return LightningCLI(subclass_mode_model=True, subclass_mode_data=True,
                            trainer_defaults=trainer_defaults, run=run)
    argv, sys.argv = sys.argv, sys.argv[:1]  # LightningCLI reads ``args``, not our argv
    try:
        return LightningCLI(subclass_mode_model=True, subclass_mode_data=True,
                            trainer_defaults=trainer_defaults, args=args, run=run)
    finally:
        sys.argv = argv
