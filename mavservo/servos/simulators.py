"""Every built-in family's simulated device, registered by profile name (:mod:`.sim_registry`).

Imported by the package, so a profile's ``sim_device`` finds its device wherever the profile is
used; the devices themselves live in ``<family>_sim`` modules that import nothing of their
profiles.
"""

from __future__ import annotations

from . import (
    cubemars_mit_sim,
    cubemars_sim,
    damiao_sim,
    lk_sim,
    odrive_sim,
    rmdx_sim,
    robstride_sim,
)
from .sim_registry import register

register("rmd-x", rmdx_sim.RmdXV4Device)
register("lk", lk_sim.LkMotorDevice)
register("cubemars-ak", cubemars_sim.AkServoModeDevice)
register("cubemars-ak-mit", cubemars_mit_sim.AkMitModeDevice)
register("damiao-dm", damiao_sim.DmJMotorDevice)
register("odrive", odrive_sim.OdriveAxisDevice)
register("robstride", robstride_sim.RsMotorDevice)
