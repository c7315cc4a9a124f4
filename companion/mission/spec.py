"""Mission file (YAML) schema and loading: every field validated, every error names the field and the fix."""

from __future__ import annotations

import difflib
import json
import math
from pathlib import Path
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator, model_validator

from companion.errors import CompanionError
from companion.resources import SHIPPED_MODEL_FILES

# Below this standoff a gust or a GPS glitch can put the propellers into the wall.
MIN_SAFE_STANDOFF_M = 2.0
STANDOFF_HOLD_TOLERANCE_M = 0.3  # the flight's default standoff tolerance (companion.flight.standoff_control)


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class LatLon(_Strict):
    lat: float = Field(ge=-90.0, le=90.0)
    lon: float = Field(ge=-180.0, le=180.0)

    @field_validator("lat", "lon")
    @classmethod
    def _finite(cls, v: float) -> float:
        if not math.isfinite(v):
            raise ValueError("must be a finite number of degrees")
        return v


class Footprint(_Strict):
    """Building footprint polygon; ``faces`` are edge indices (edge i runs from vertex i to vertex i+1)."""

    geojson: str | None = None  # path (relative to the mission file) of a GeoJSON Polygon / Feature
    coordinates: list[tuple[float, float]] | None = None  # inline [lon, lat] ring, GeoJSON order
    face: int = Field(default=0, ge=0)

    @model_validator(mode="after")
    def _one_source(self) -> Footprint:
        if (self.geojson is None) == (self.coordinates is None):
            raise ValueError("give exactly one of 'geojson' (file path) or 'coordinates' ([lon, lat] ring)")
        return self


class Facade(_Strict):
    start: LatLon | None = None
    end: LatLon | None = None
    footprint: Footprint | None = None
    ground_alt_amsl_m: float = Field(ge=-500.0, le=9000.0)
    height_m: float = Field(gt=0.0, le=500.0)

    @model_validator(mode="after")
    def _wall_given(self) -> Facade:
        if self.footprint is None and (self.start is None or self.end is None):
            raise ValueError("give the wall as 'start' and 'end', or as a building 'footprint' with a 'face'")
        if self.footprint is not None and (self.start is not None or self.end is not None):
            raise ValueError("give either 'start'/'end' or 'footprint', not both")
        return self


class Camera(_Strict):
    width_px: int = Field(ge=64, le=20000)
    height_px: int = Field(ge=64, le=20000)
    hfov_deg: float = Field(gt=5.0, lt=170.0)
    fps: float = Field(gt=0.0, le=240.0)
    exposure_s: float = Field(gt=0.0, le=0.1)
    # Written into the keyframe images' EXIF (docs/OUTPUTS.md): tools group images and look up sensors by these.
    make: str | None = Field(default=None, min_length=1, max_length=60)
    model: str | None = Field(default=None, min_length=1, max_length=60)
    # Width of the image area on the sensor; gives the true lens focal in mm (without it: the 35 mm equivalent).
    sensor_width_mm: float | None = Field(default=None, gt=0.5, le=100.0)
    # Calibration file (intrinsics + distortion, companion/spool/camera.py), relative to the mission file.
    calibration: str | None = Field(default=None, min_length=1)

    @property
    def vfov_deg(self) -> float:
        half_h = math.tan(math.radians(self.hfov_deg) / 2.0) * self.height_px / self.width_px
        return math.degrees(2.0 * math.atan(half_h))


class Takeoff(_Strict):
    lat: float = Field(ge=-90.0, le=90.0)
    lon: float = Field(ge=-180.0, le=180.0)
    ground_alt_amsl_m: float | None = None  # defaults to the facade's ground altitude


class Margins(_Strict):
    ends_m: float = Field(default=2.0, ge=0.0, le=50.0)  # past each wall end
    roof_m: float = Field(default=2.0, ge=0.0, le=50.0)  # above the roof line
    bottom_clearance_m: float = Field(default=2.0, ge=0.5, le=50.0)  # lowest flight height above ground
    # PX4 only: nothing less than home's largest move + 1 m above home (3.5 m) is flown until this long after
    # take-off (the strips' upper parts first, their bottoms after; a hold above only when that part is shorter),
    # because PX4 moves home's altitude, and every mission altitude with it, for 120 s after take-off
    # (docs/FLIGHT.md); 0 flies the plain plan at once (the flight's home watch still stops a scan that home moved
    # too low)
    home_settle_s: float = Field(default=120.0, ge=0.0, le=600.0)


class Geofence(_Strict):
    max_alt_m: float = Field(default=120.0, gt=0.0, le=1000.0)  # above home
    max_distance_m: float = Field(default=500.0, gt=0.0, le=20000.0)  # horizontal, from home


class Mission(_Strict):
    name: str = Field(min_length=1, max_length=80)
    facade: Facade
    standoff_m: float = Field(gt=0.0, le=100.0)
    allow_unsafe_standoff: bool = False
    # The closest the drone may truly come to the wall in flight, as measured (forward rangefinder, camera): below
    # it the flight backs off and ends unless the measurement recovers. None: 60 % of the standoff.
    min_distance_m: float | None = Field(default=None, gt=0.0)
    overlap: float = Field(gt=0.0, lt=1.0)
    side_overlap: float = Field(default=0.60, ge=0.1, le=0.95)
    camera: Camera
    pattern: Literal["vertical", "horizontal"] = "vertical"
    takeoff: Takeoff | None = None
    transit_alt_m: float | None = Field(default=None, gt=0.0)  # above home; default: roof line + margin
    entrance_alt_m: float | None = Field(default=None, gt=0.0)  # above home, approach to the first strip
    exit_alt_m: float | None = Field(default=None, gt=0.0)  # above home, leaving the last strip
    margins: Margins = Margins()
    max_speed_m_s: float = Field(default=5.0, gt=0.0, le=20.0)
    motion_blur_budget_px: float = Field(default=1.0, gt=0.0, le=20.0)
    min_frames_per_keyframe: int = Field(default=10, ge=2, le=1000)
    # Frames per second the companion can actually process (depth mask + gate); the speed limit uses the lower of
    # this and the camera fps. About 3 on a 2-core companion at 640 px (docs/BENCHMARKS.md, Onboard pipeline).
    onboard_fps: float | None = Field(default=None, gt=0.0, le=240.0)
    gimbal_pitch_deg: float = Field(default=0.0, ge=-90.0, le=30.0)
    # Monodepth2-style ONNX depth model for the background mask: a shipped model's name ("sim", "real-nc") or a file
    # relative to the mission file; None: the shipped default. A command's --model overrides it.
    depth_model: str | None = Field(default=None, min_length=1)
    end_action: Literal["land", "rtl"] = "land"
    geofence: Geofence = Geofence()

    @field_validator("overlap")
    @classmethod
    def _overlap_range(cls, v: float) -> float:
        if not 0.5 <= v <= 0.95:
            raise ValueError("overlap must be between 0.50 and 0.95 (the paper uses 0.80)")
        return v

    @field_validator("min_distance_m")
    @classmethod
    def _floor_below_standoff(cls, v: float | None, info: ValidationInfo) -> float | None:
        standoff = info.data.get("standoff_m")
        if v is not None and standoff is not None and v >= standoff - STANDOFF_HOLD_TOLERANCE_M:
            raise ValueError(f"min_distance_m must be below standoff_m - {STANDOFF_HOLD_TOLERANCE_M} m (the flight "
                             f"holds the standoff within that); {v} m with a standoff of {standoff} m leaves no room")
        return v

    @model_validator(mode="after")
    def _safe_standoff(self) -> Mission:
        if self.standoff_m < MIN_SAFE_STANDOFF_M and not self.allow_unsafe_standoff:
            raise ValueError(
                f"standoff_m={self.standoff_m} is below the safe minimum of {MIN_SAFE_STANDOFF_M} m; "
                "increase it, or set allow_unsafe_standoff: true if you really mean it"
            )
        return self


_FIELD_FIXES = {
    "overlap": "use a fraction between 0.50 and 0.95, e.g. overlap: 0.80",
    "min_distance_m": "set min_distance_m below the standoff (e.g. 60 % of it), or leave it out for that default",
    "standoff_m": f"use a standoff of at least {MIN_SAFE_STANDOFF_M} m (the paper flies at 4 m)",
    "camera": "check the camera block: width_px, height_px, hfov_deg (5..170), fps, exposure_s (seconds); optional "
    "make, model, sensor_width_mm, calibration",
    "facade": "give facade.start/end as {lat, lon} (or a footprint), ground_alt_amsl_m and height_m",
}


# pydantic's error type prefix (float_parsing, int_type, ...) -> what the field wants, in a user's words
_TYPE_WANTED = {"float": "a number", "int": "a whole number", "bool": "true or false", "string": "text",
                "dict": "a mapping of fields", "model": "a mapping of fields", "list": "a list"}


def _format_validation_error(path: Path, exc: ValidationError) -> CompanionError:
    lines = []
    fixes = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
        if err["type"] == "extra_forbidden":
            parent_model = _model_at(err["loc"][:-1])
            known = list(parent_model.model_fields) if parent_model else []
            guess = difflib.get_close_matches(str(err["loc"][-1]), known, n=1)
            hint = f" (did you mean '{guess[0]}'?)" if guess else ""
            lines.append(f"unknown field '{loc}'{hint}")
            fixes.append(f"remove or rename '{loc}'; allowed here: {', '.join(known)}")
        elif err["type"] == "missing":
            lines.append(f"missing field '{loc}'")
            fixes.append(f"add '{loc}' (see missions/demo-facade.yaml)")
        elif not err["loc"] and err["type"] == "value_error":  # a rule across fields: its message says both
            problem, _, fix = str(err["msg"]).removeprefix("Value error, ").partition("; ")
            lines.append(problem)
            fixes.append(fix or "see missions/demo-facade.yaml")
        else:
            got = err.get("input")
            got_text = "" if isinstance(got, dict | list) else f" (got {got!r})"
            lines.append(f"field '{loc}': {err['msg']}{got_text}")
            top = str(err["loc"][0]) if err["loc"] else ""
            wrong_type = str(err["type"]).endswith(("_type", "_parsing"))
            kind = _TYPE_WANTED.get(str(err["type"]).split("_")[0]) if wrong_type else None
            # a value of the wrong type: say the type (the field's range fix would answer another question)
            fixes.append(f"write '{loc}' as {kind} (see missions/demo-facade.yaml)" if kind else
                         _FIELD_FIXES.get(top, f"correct '{loc}' in {path.name}"))
    return CompanionError(f"invalid mission file {path}:\n    " + "\n    ".join(lines), "; ".join(dict.fromkeys(fixes)))


def _model_at(loc: tuple) -> type[BaseModel] | None:
    model: type[BaseModel] = Mission
    for part in loc:
        field = model.model_fields.get(str(part))
        if field is None:
            return None
        ann = field.annotation
        candidates = [ann, *getattr(ann, "__args__", ())]
        nxt = next((c for c in candidates if isinstance(c, type) and issubclass(c, BaseModel)), None)
        if nxt is None:
            return None
        model = nxt
    return model


def parse_mission(data: object, source: Path | str = "<mission>") -> Mission:
    """Validate an already-parsed YAML/JSON mapping."""
    path = Path(source)
    if not isinstance(data, dict):
        raise CompanionError(
            f"mission file {path} must be a YAML mapping of fields, got {type(data).__name__}",
            "start from missions/demo-facade.yaml",
        )
    try:
        mission = Mission.model_validate(data)
    except ValidationError as exc:
        raise _format_validation_error(path, exc) from None
    return mission


def load_mission(path: str | Path) -> Mission:
    """Read and validate a mission YAML file; a footprint GeoJSON path is resolved next to the file."""
    path = Path(path)
    if not path.is_file():
        raise CompanionError(f"mission file {path} does not exist", "check the path (examples are in missions/)")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise CompanionError(f"mission file {path} is not valid YAML: {exc}", "fix the YAML syntax") from None
    except UnicodeDecodeError:
        raise CompanionError(f"mission file {path} is not UTF-8 text", "save it as UTF-8 YAML") from None
    mission = parse_mission(data, path)
    fp = mission.facade.footprint
    if fp is not None and fp.geojson is not None:
        ring = read_footprint_geojson(path.parent / fp.geojson)
        facade = mission.facade.model_copy(
            update={"footprint": fp.model_copy(update={"geojson": None, "coordinates": ring})}
        )
        mission = mission.model_copy(update={"facade": facade})
    if mission.camera.calibration is not None:
        calibration = (path.parent / mission.camera.calibration).resolve()
        if not calibration.is_file():
            raise CompanionError(
                f"mission file {path}: camera.calibration {mission.camera.calibration} does not exist "
                f"(looked for {calibration})",
                "give the calibration file's path relative to the mission file, or remove camera.calibration",
            )
        camera = mission.camera.model_copy(update={"calibration": str(calibration)})
        mission = mission.model_copy(update={"camera": camera})
    if mission.depth_model is not None and mission.depth_model not in SHIPPED_MODEL_FILES:  # a name stays a name
        model = (path.parent / mission.depth_model).resolve()
        if not model.is_file():
            raise CompanionError(
                f"mission file {path}: depth_model {mission.depth_model} does not exist (looked for {model})",
                "set depth_model to a Monodepth2-style .onnx file, relative to the mission file, or to a shipped "
                "model's name (sim, real-nc), or remove it to use the shipped default",
            )
        mission = mission.model_copy(update={"depth_model": str(model)})
    return mission


def read_footprint_geojson(path: Path) -> list[tuple[float, float]]:
    """Outer ring ([lon, lat] pairs) of the first Polygon in a GeoJSON file."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CompanionError(f"footprint file {path} does not exist", "fix facade.footprint.geojson") from None
    except json.JSONDecodeError as exc:
        raise CompanionError(f"footprint file {path} is not valid JSON: {exc}", "fix the GeoJSON") from None
    geoms = []
    if doc.get("type") == "FeatureCollection":
        geoms = [f.get("geometry") or {} for f in doc.get("features", [])]
    elif doc.get("type") == "Feature":
        geoms = [doc.get("geometry") or {}]
    else:
        geoms = [doc]
    for g in geoms:
        if g.get("type") == "Polygon" and g.get("coordinates"):
            return [(float(p[0]), float(p[1])) for p in g["coordinates"][0]]
    raise CompanionError(f"footprint file {path} holds no Polygon", "give a GeoJSON Polygon of the building outline")
