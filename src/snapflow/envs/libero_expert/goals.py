"""Which controller achieves a LIBERO goal: the one place that reads a task's BDDL goal predicates."""

from __future__ import annotations

import re
from collections.abc import Sequence

from snapflow.envs.libero_expert.clear import ClearDrawer
from snapflow.envs.libero_expert.fixtures import CloseDrawer, OpenDrawer, OpenTopDrawer, TurnOn
from snapflow.envs.libero_expert.microwave import CloseMicrowave, IntoMicrowave
from snapflow.envs.libero_expert.motion import Primitive
from snapflow.envs.libero_expert.pick_and_place import BOWLS, PickAndPlace
from snapflow.envs.libero_expert.push import PUSHED, Push
from snapflow.envs.libero_expert.sequence import InSequence
from snapflow.errors import InvalidInputError

OBJECT_NAME = r"[a-z_]+_\d+"  # an object instance of a BDDL scene (plate_1); regions and sides end otherwise
# fixture sites an object is put on from above (not into: drawers, the microwave, the caddy's compartments)
SURFACES = ("_cook_region", "_top_side", "wine_rack_1_top_region")
CADDY_SLOT = r"desk_caddy_\d+_(back|front)_contain_region"  # the caddy's compartments long along y
TABLE_REGION = r"[a-z_]+_table_[a-z_]+_region"  # a region of the table (to the right of the plate, ...)
DRAWER = r"(.+_cabinet_\d+)_(top|middle|bottom)_region"  # a cabinet's drawer: its cabinet and level
MICROWAVE = r"microwave_\d+"
# objects put on one fixture's surface side by side stand this far apart along x (the first the farthest)
SHARED_SURFACE_SPACING = 0.09

LiberoExpert = Primitive | InSequence


class NoExpertError(InvalidInputError):
    """No scripted controller covers this task's goal."""


def _primitive(predicate: str, arguments: Sequence[str]) -> Primitive | None:
    """The controller of one goal predicate, or None where none covers it."""
    drawer = re.fullmatch(DRAWER, arguments[-1]) if arguments else None
    if predicate == "open" and len(arguments) == 1 and drawer:
        return OpenDrawer(*drawer.groups())
    if predicate == "close" and len(arguments) == 1 and drawer:
        return CloseDrawer(*drawer.groups())
    if predicate == "turnon" and len(arguments) == 1 and arguments[0].startswith("flat_stove"):
        return TurnOn(arguments[0])
    if predicate == "close" and len(arguments) == 1 and re.fullmatch(MICROWAVE, arguments[0]):
        return CloseMicrowave(arguments[0])
    if predicate in ("on", "in") and len(arguments) == 2 and re.fullmatch(OBJECT_NAME, arguments[0]):
        obj, target = arguments
        microwave = re.fullmatch(f"({MICROWAVE})_heating_region", target)
        if microwave and "_mug_" in obj:  # a mug, gripped by its rim (read from the scene)
            return IntoMicrowave(obj, microwave.group(1))
        if re.fullmatch(CADDY_SLOT, target):  # a compartment of the desk caddy: upright, its thin side along x
            return PickAndPlace(obj, target, onto_site=True, slot_yaw=0.0)
        target = target.removesuffix("_contain_region")  # "in the basket": over the basket itself
        if re.fullmatch(OBJECT_NAME, target):
            return PickAndPlace(obj, target)
        if target.startswith("main_table_") and obj.startswith(PUSHED):  # a region of the table: slide it there
            return Push(obj, target)
        # a fixture's surface or a region of the table (a site): from the extras
        if target.endswith(SURFACES) or re.fullmatch(TABLE_REGION, target):
            return PickAndPlace(obj, target, onto_site=True)
        if drawer:  # into a drawer the goal shuts afterwards, so open from the start (see make_libero_expert)
            return PickAndPlace(obj, target, onto_site=True, drawer="_".join(drawer.groups()))
    return None


def _share_surfaces(steps: Sequence[Primitive]) -> None:
    """Spread the objects put on one fixture's surface along x, so that each stands clear of the others."""
    for target in {step.target for step in steps if isinstance(step, PickAndPlace) and step.onto_site}:
        sharing = [step for step in steps if isinstance(step, PickAndPlace) and step.target == target]
        for index, step in enumerate(sharing):
            step.offset[0] = SHARED_SURFACE_SPACING * ((len(sharing) - 1) / 2 - index)


def _into_top_drawer(goal_state: Sequence[Sequence[str]]) -> InSequence | None:
    """The controller of "open the top drawer and put the bowl inside" (LIBERO-Goal's task 3: a bowl into a top
    drawer that starts shut, the drawer's opening asked for or not), or None for any other goal. The open drawer would
    stand over the bowl beside it, 1-2 cm from every grip of its rim: the bowl is dragged clear first, the drawer opened
    from above (nothing stands over a top drawer's handle), then the bowl put in, gripped on its rim's side facing out
    of the drawer."""
    into = [predicate for predicate in goal_state if predicate[0] == "in" and len(predicate) == 3]
    drawer = re.fullmatch(DRAWER, into[0][2]) if len(into) == 1 else None
    if not drawer or drawer.group(2) != "top" or not into[0][1].startswith(BOWLS):  # a bowl: dragged from inside
        return None
    (_, obj, region), (cabinet, level) = into[0], drawer.groups()
    if any(tuple(predicate) not in (tuple(into[0]), ("open", region)) for predicate in goal_state):
        return None
    put = PickAndPlace(obj, region, onto_site=True, drawer=f"{cabinet}_{level}", rim_out=True)
    return InSequence([ClearDrawer(obj, cabinet, level), OpenTopDrawer(cabinet, level), put])


def _in_order(goal_state: Sequence[Sequence[str]]) -> list[tuple[str, ...]]:
    """The goal's predicates in the order they are achieved: what goes into a drawer before the drawer is shut. An
    object into a drawer that the goal does not shut (a drawer that starts shut) is left out, so the goal is refused,
    except where :func:`_into_top_drawer` covers it."""
    predicates = sorted((tuple(predicate) for predicate in goal_state), key=lambda predicate: predicate[0] == "close")
    shut = {predicate[1] for predicate in predicates if predicate[0] == "close"}
    return [p for p in predicates if not (p[0] == "in" and re.fullmatch(DRAWER, p[-1]) and p[-1] not in shut)]


def make_libero_expert(goal_state: Sequence[Sequence[str]]) -> LiberoExpert:
    """The controller of a LIBERO goal (its BDDL ``goal_state``), or :class:`NoExpertError` naming it."""
    filling = _into_top_drawer(goal_state)
    if filling is not None:
        return filling
    predicates = _in_order(goal_state)
    steps = [_primitive(predicate, arguments) for predicate, *arguments in predicates]
    if not steps or None in steps or len(predicates) < len(goal_state):
        raise NoExpertError(f"no scripted controller covers the goal {[list(predicate) for predicate in goal_state]}")
    if len(steps) == 1:
        return steps[0]
    _share_surfaces(steps)
    for step in steps:
        if isinstance(step, PickAndPlace):
            step.over_others = True
    return InSequence(steps)
