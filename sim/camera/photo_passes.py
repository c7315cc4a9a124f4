"""The named real-texture passes of the mask evaluation, built only from held-out photos.

Each pass names its wall photo, how wide that wall is in metres (a plausible real size, so windows are window
sized at the 4 m standoff), the background photo and its distance. ``companion.depth.training.realdata`` owns the split;
a photo that training may see is refused here, so no figure is ever reported on a training photo.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import cv2

from companion.depth.training.realdata import RealPhoto, facade_mask, list_real_photos, load_image
from companion.errors import CompanionError
from evaluation.shared_data import shared_data_root
from sim.camera.photo_scene import PhotoPass, PhotoTexture


@dataclass(frozen=True)
class PassRecipe:
    """Which photos make a pass and at what size; ``strips_up`` are camera heights as fractions of the wall."""

    name: str
    wall_photo: str  # file name in the photo index
    wall_width_m: float
    background_photo: str
    background_distance_m: float = 120.0
    strips_up: tuple[float, ...] = (0.5,)
    description: str = ""


RECIPES: dict[str, PassRecipe] = {r.name: r for r in (
    PassRecipe("ornate-entry", "entry-P10_0004.jpg", 12.0,
               "static_street_outdoor_palma_mallorca_spain__IMG_0693.jpg",
               description="Strecha entry-P10 (baroque entrance: arched doorway, columns, balcony, window "
                           "surrounds), frontal view, the whole photo is facade; background: Palma roofs, "
                           "cathedral, trees, sky"),
    PassRecipe("cmp-balconies", "cmp_b0283.jpg", 16.0,
               "static_outdoor_street_village_puigpunyent_mallorca_spain__IMG_4218.jpg", strips_up=(0.45, 0.9),
               description="CMP b0283 (six floors, window rows, iron balconies, shop front), CMP background "
                           "cut out of the wall; strips at mid-height and along the roof line; background: "
                           "trees, houses, sky"),
    PassRecipe("dji-plain-wall", "DJI_0977_rgb.JPG", 7.3,
               "static_outdoor_street_city_cambridge_uk__IMG_8918.jpg",
               description="DJI Mavic 2 photo of a plain grey clad wall with a window at its right edge; "
                           "background: King's College chapel, trees, sky"),
    PassRecipe("cmp-roofline-40m", "cmp_b0292.jpg", 14.0,
               "static_outdoor_street_village_puigpunyent_mallorca_spain__IMG_4213.jpg",
               background_distance_m=40.0, strips_up=(0.55, 0.88),
               description="CMP b0292 (a house with balconies, roof and sky around it, cut out of the wall); "
                           "background 40 m behind: hills, trees"),
)}
DEFAULT_PASSES = ("ornate-entry", "cmp-balconies", "dji-plain-wall", "cmp-roofline-40m")


def _find(name: str, photos: list[RealPhoto]) -> RealPhoto | Path:
    """The indexed photo of that file name (refused when it is a training photo), or a photo file outside the
    index given by its path (anyone's photos: the split cannot be checked, so that is the caller's promise)."""
    for p in photos:
        if p.image.name == name:
            if p.split != "heldout":
                raise CompanionError(f"{name} is in the training split",
                                     "report figures only on held-out photos (companion.depth.training.realdata)")
            return p
    if Path(name).is_file():
        return Path(name)
    raise CompanionError(f"photo {name} not found in the real photo index nor as a file",
                         "give a file name from the shared data folder (held-out split) or the path of a photo")


def _texture(photo: RealPhoto | Path, width_m: float) -> PhotoTexture:
    if isinstance(photo, Path):
        image = cv2.imread(str(photo), cv2.IMREAD_COLOR)
        if image is None:
            raise CompanionError(f"cannot read {photo} as an image", "pass a JPEG/PNG photo")
        return PhotoTexture(photo.name, image, width_m)  # no labels: the whole photo is wall (or background)
    return PhotoTexture(photo.image.name, load_image(photo), width_m, facade_mask(photo))


def parse_recipe(text: str) -> PassRecipe:
    """``NAME:WALL:WIDTH_M:BACKGROUND[:DISTANCE_M]`` (photos by index file name or path) -> a recipe."""
    parts = text.split(":")
    try:
        name, wall, width, background = parts[:4]
        distance = float(parts[4]) if len(parts) > 4 else 120.0
        return PassRecipe(name, wall, float(width), background, distance,
                          description=f"custom pass: {wall} ({width} m wide), {background} at {distance:.0f} m")
    except (ValueError, IndexError) as exc:
        raise CompanionError(f"bad pass {text!r}", "use NAME:WALL_PHOTO:WALL_WIDTH_M:BACKGROUND_PHOTO[:DISTANCE_M]") \
            from exc


def build_pass(recipe: PassRecipe, *, root: Path | None = None, frames: int = 250, background_frames: int = 22,
               background_distance_m: float | None = None) -> PhotoPass:
    """The :class:`PhotoPass` of a recipe (wall photo with its facade labels as alpha, background photo), its photos
    from the shared data folder ``root`` (None: ``$COMPANION_SHARED_DATA``, ``evaluation.shared_data``)."""
    photos = list_real_photos(shared_data_root(root))
    wall = _texture(_find(recipe.wall_photo, photos), recipe.wall_width_m)
    background = _texture(_find(recipe.background_photo, photos), 1.0)
    distance = background_distance_m if background_distance_m is not None else recipe.background_distance_m
    spec = PhotoPass(recipe.name, wall, background, background_distance_m=distance, frames=frames,
                     background_frames=background_frames)
    return replace(spec, strips_up_m=tuple(f * wall.height_m for f in recipe.strips_up))
