"""Training: the student and expert LightningModules, the diffusion margin, callbacks, checkpoint loading."""
