"""Every built-in family's simulated device, registered by profile name (:mod:`.sim_registry`).

Imported by the package, so a profile's ``sim_device`` finds its device wherever the profile is
used; the devices themselves live in each family's ``sim`` module, which imports nothing of its
profile.
"""

from __future__ import annotations

from .cubemars import mit_mode_sim as cubemars_mit_sim
from .cubemars import sim as cubemars_sim
from .damiao import sim as damiao_sim
from .lk import sim as lk_sim
from .odrive import sim as odrive_sim
from .rmdx import sim as rmdx_sim
from .robstride import sim as robstride_sim
from .sim_registry import register

register("rmd-x", rmdx_sim.RmdXV4Device)
register("lk", lk_sim.LkMotorDevice)
register("cubemars-ak", cubemars_sim.AkServoModeDevice)
register("cubemars-ak-mit", cubemars_mit_sim.AkMitModeDevice)
register("damiao-dm", damiao_sim.DmJMotorDevice)
register("odrive", odrive_sim.OdriveAxisDevice)
register("robstride", robstride_sim.RsMotorDevice)
