"""Train a decoder from a config: ``python train.py fit --config configs/fluid.yaml``.

Resume an interrupted run with ``--ckpt_path runs/fluid/checkpoints/last.ckpt``. See
``wtml/training.py`` for the defaults.
"""

from wtml.training import cli_main

if __name__ == "__main__":
    cli_main()
