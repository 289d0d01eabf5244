"""Train a decoder from a config file: ``python train.py fit --config configs/NAME.yaml``.

A thin LightningCLI entry point: the config names the LightningModule (``model.class_path``)
and the LightningDataModule (``data.class_path``) from ``wtml``. Logging goes to CSV files
under ``runs/`` unless the config says otherwise, and the progress bar is off under CI
(``CI`` set in the environment).
"""

import os

from lightning.pytorch.cli import LightningCLI


def cli_main(args=None) -> LightningCLI:
    trainer_defaults = {
        "logger": {"class_path": "lightning.pytorch.loggers.CSVLogger",
                   "init_args": {"save_dir": "runs"}},
        "enable_progress_bar": not os.environ.get("CI"),
        "accelerator": "auto",
    }
    return LightningCLI(subclass_mode_model=True, subclass_mode_data=True,
                        trainer_defaults=trainer_defaults, args=args)


if __name__ == "__main__":
    cli_main()
