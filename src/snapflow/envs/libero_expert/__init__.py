"""Scripted experts for LIBERO: waypoint controllers that steer by the simulator's object poses.

LIBERO ships human demonstrations only (on a hub), no expert; these controllers replace them. They read
:attr:`~snapflow.envs.base.Observation.privileged` (robosuite's object poses, plus what :func:`privileged_extras`
adds), never shown to a policy, and act through LIBERO's OSC_POSE controller: a 7-D action in [-1, 1] of translation
(1 = 5 cm of target offset), rotation (1 = 0.5 rad) and gripper (-1 open, +1 closed).

Each primitive is a module: pick-and-place (``pick_and_place.py``) covers every task of LIBERO-Spatial ("pick up the
black bowl ... and place it on the plate") and LIBERO-Object ("pick up the X and place it in the basket"), and the
goals of the same form whose target is an object (the plate, the basket, the bowl), a fixture's surface (the stove's
burner, the cabinet's top, the wine rack) or a region of the table ("to the right of the plate"); mugs are gripped by
the rim clear of their handle, the moka pot and the wine bottle below the top read from their geoms (``scene.py``), a
book across its thickness, turned on the way to stand upright in the caddy's compartment. A
fixture's joint (``fixtures.py``: "open the middle drawer", "turn on the stove", a drawer pushed shut); a push (``push.py``: "push the plate
to the front of the stove"). A goal of several predicates (LIBERO-10's "put both ... in the basket") runs their
primitives in sequence (``sequence.py``): "put the black bowl in the bottom drawer and close it" puts the bowl near
the open drawer's front, then pushes the drawer shut; "open the top drawer and put the bowl inside" (LIBERO-Goal's
task 3) drags the bowl clear of the drawer's way (``clear.py``: the open drawer would stand over it), opens the drawer
from above and puts the bowl in, gripped on the rim's side facing out of it; "put the yellow and white mug in the
microwave and close it" (LIBERO-10's task 9, ``microwave.py``) carries the mug by its rim, the hand pitched into the
microwave's mouth, lets it go just inside and pushes the door shut, which pushes the mug the rest of the way in.
``goals.py`` maps a goal to its controller; any other (an object into a middle or bottom drawer that starts shut, or
anything but a mug into the microwave) raises :class:`NoExpertError` naming it.
"""

from snapflow.envs.libero_expert.clear import ClearDrawer
from snapflow.envs.libero_expert.fixtures import CloseDrawer, OpenDrawer, OpenTopDrawer, TurnOn
from snapflow.envs.libero_expert.goals import LiberoExpert, NoExpertError, make_libero_expert
from snapflow.envs.libero_expert.microwave import CloseMicrowave, IntoMicrowave
from snapflow.envs.libero_expert.pick_and_place import PickAndPlace
from snapflow.envs.libero_expert.push import Push
from snapflow.envs.libero_expert.scene import privileged_extras
from snapflow.envs.libero_expert.sequence import InSequence

__all__ = [
    "ClearDrawer",
    "CloseDrawer",
    "CloseMicrowave",
    "InSequence",
    "IntoMicrowave",
    "LiberoExpert",
    "NoExpertError",
    "OpenDrawer",
    "OpenTopDrawer",
    "PickAndPlace",
    "Push",
    "TurnOn",
    "make_libero_expert",
    "privileged_extras",
]
