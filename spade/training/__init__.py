"""Training: the DataModule, the student and expert LightningModules, the diffusion margin, callbacks."""
