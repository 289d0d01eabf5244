"""Decoders: plain nn.Modules (exported) and their LightningModules (trained)."""
