"""cmal-lcd's SLURM launcher as a Hydra plugin (Hydra instantiates launchers only from the
``hydra_plugins`` package): the logic is :mod:`cmal_lcd.slurm`."""

from hydra_plugins.hydra_submitit_launcher.submitit_launcher import (
    SlurmLauncher as SubmititSlurmLauncher)


class SlurmLauncher(SubmititSlurmLauncher):
    """submitit's SLURM launcher, checked before it submits and bounded after
    (:func:`cmal_lcd.slurm.launch_checked`)."""

    def launch(self, job_overrides, initial_job_idx):
        from cmal_lcd.slurm import launch_checked

        return launch_checked(self, job_overrides, initial_job_idx)
