"""``GET /v1/plants``: the built-in plant models with their documented parameters and units."""

from __future__ import annotations

import logging

from fastapi import APIRouter

from gaintune_api.deps import require_key
from gaintune_api.problem_details import ApiError
from gaintune_api.schemas import ParamPublic, PlantList, PlantPublic, SignalPublic

router = APIRouter(prefix="/v1", tags=["plants"], dependencies=[require_key])
log = logging.getLogger("gaintune.api")


def _public(name: str) -> PlantPublic:
    from gaintune.plants import build_plant
    from gaintune.plants.library import load_model

    m = load_model(name)
    try:
        order = build_plant(m.plant).order
    except Exception:  # noqa: BLE001 - a model that cannot build is still listed
        order = None
    return PlantPublic(
        name=m.name, title=m.title, description=m.description.strip(),
        parameters={k: ParamPublic(value=p.value, unit=p.unit, description=p.description)
                    for k, p in m.parameters.items()},
        input=SignalPublic(unit=m.input.unit, description=m.input.description),
        outputs={k: SignalPublic(unit=o.unit, description=o.description) for k, o in m.outputs.items()},
        order=order, plant=m.plant.model_dump(mode="json", exclude_none=True), example_spec=m.example_spec(),
    )


@router.get("/plants", response_model=PlantList, summary="Built-in plant models")
def list_plants() -> PlantList:
    """The built-in plant models, each with an example spec."""
    from gaintune.plants.library import list_models

    items = []
    for name in list_models():
        try:
            items.append(_public(name))
        except Exception:  # noqa: BLE001 - skip a broken model file, but say so in the log
            log.warning("built-in model %s could not be loaded", name, exc_info=True)
    return PlantList(items=items)


@router.get("/plants/{name}", response_model=PlantPublic, summary="One built-in plant model",
            responses={404: {"description": "No such model.", "content": {"application/problem+json": {}}}})
def get_plant(name: str) -> PlantPublic:
    """The built-in plant model ``name``."""
    from gaintune.plants.library import list_models

    if name not in list_models():
        raise ApiError(404, f"No built-in model {name!r}.")
    return _public(name)
