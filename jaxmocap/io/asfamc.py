"""Acclaim skeleton (ASF) and motion (AMC) files, as used by the CMU motion-capture database.

ASF: ``:units`` (``length f``: file lengths times ``1/f`` are inches; ``angle deg|rad``), ``:root`` (``order``
of the AMC root values, ``axis`` order, ``position``, ``orientation``), ``:bonedata`` (per bone ``name``, unit
``direction`` and ``length`` in the global frame of the rest pose, ``axis a b c XYZ`` the bone's local frame,
``dof`` and ``limits``), ``:hierarchy`` (``parent child child ...``). AMC (``:FULLY-SPECIFIED``,
``:DEGREES``): a frame number line, then one line per bone with its dof values in the ASF ``dof`` order.

Forward kinematics. Every bone starts at the end of its parent (the root's children at the root position) and
ends ``length · direction`` further along, rotated by the world rotation of the bone:

.. math::

    W_b = W_{p(b)} L_b, \\quad L_b = C_b M_b C_b^{-1}, \\quad
    \\text{end}_b = \\text{start}_b + W_b\\, \\ell_b d_b

where ``C_b`` is the ``axis`` rotation (order ``XYZ``: ``C = Rz(a_z) Ry(a_y) Rx(a_x)``) and ``M_b`` composes
the dof rotations in the order listed, the first applied first (``dof rx ry rz``: ``M = Rz Ry Rx``). The root
uses ``L = C M C⁻¹`` with ``C`` from ``orientation`` (``axis`` order) and ``M`` from the AMC rotations in the
``order`` listed; its position is the AMC translation (components the AMC does not give keep the ASF
``position``). In the resulting :class:`~jaxmocap.io.mocap.Motion` the joint of bone ``b`` is its start, its
rotation is ``L_b``, and bones without children get an end site at ``ℓ_b d_b``.

Units: metres per file unit ``= 0.0254 / f`` (``length 0.45`` gives 0.05644 m). Axes: CMU files are y-up and
``up_axis="y"`` maps them to z-up by ``(x, y, z) -> (z, x, y)``. Translation (``tx ty tz``) and length (``l``)
dofs on bones are not supported and raise :class:`MocapInputError`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re

import numpy as np

from jaxmocap.errors import MocapInputError
from jaxmocap.io.mocap import INCH, Motion, build_motion, euler_to_matrix, read_lines

#: Numbers beyond this magnitude are rejected as malformed (they would overflow the kinematics).
MAX_ABS = 1e12

_ROT_DOFS = ("rx", "ry", "rz")
_LIMIT_RE = re.compile(r"\(\s*([^\s()]+)\s+([^\s()]+)\s*\)")
_INT_RE = re.compile(r"-?[0-9]+")


@dataclasses.dataclass(frozen=True)
class Bone:
    """One ASF bone (file units, file axes; angles in radians)."""

    name: str
    direction: np.ndarray  # (3,) unit vector, global frame at rest
    length: float
    axis: np.ndarray  # (3,) radians
    axis_order: str  # e.g. "XYZ"
    dofs: tuple[str, ...]  # subset of rx ry rz, in file order
    limits: tuple[tuple[float, float], ...]  # radians, one per dof (empty if not given)


@dataclasses.dataclass(frozen=True)
class Skeleton:
    """The content of an ASF file.

    Attributes:
      bones: name -> :class:`Bone`.
      children: parent name (``"root"`` or a bone) -> child bone names, in file order.
      root_order: AMC root value order, e.g. ``("TX", "TY", "TZ", "RX", "RY", "RZ")``.
      root_axis: root orientation order, e.g. ``"XYZ"``; root_position, root_orientation (radians): ``(3,)``.
      length_unit: the ``:units length`` value ``f`` (file length × 1/f = inches); angle_unit: ``"deg"``/``"rad"``.
      source: path.
    """

    bones: dict
    children: dict
    root_order: tuple[str, ...]
    root_axis: str
    root_position: np.ndarray
    root_orientation: np.ndarray
    length_unit: float
    angle_unit: str
    source: str = ""

    @property
    def scale(self) -> float:
        """Metres per file unit: ``0.0254 / length_unit``."""
        return INCH / self.length_unit

    def joint_order(self) -> list[str]:
        """``["root", bones...]`` depth first, parents before children."""
        out, stack = [], ["root"]
        while stack:
            b = stack.pop()
            out.append(b)
            stack.extend(reversed(self.children.get(b, [])))
        return out


def _floats(path, parts: list[str], n: int, what: str, line: int, allow_inf: bool = False) -> np.ndarray:
    if len(parts) != n:
        raise MocapInputError(path, f"{what} needs {n} numbers, found {len(parts)}", line)
    try:
        v = np.array([float(p) for p in parts])
    except ValueError:
        raise MocapInputError(path, f"{what}: {' '.join(parts)!r} are not all numbers", line) from None
    if np.any(np.isnan(v)) or (not allow_inf and not np.all(np.abs(v) <= MAX_ABS)):
        raise MocapInputError(path, f"{what} must be finite and at most {MAX_ABS:g} in magnitude", line)
    return v


def _axis_order(path, s: str, line: int) -> str:
    if len(s) != 3 or sorted(s.upper()) != ["X", "Y", "Z"]:
        raise MocapInputError(path, f"axis order {s!r} must be a permutation of XYZ", line)
    return s.upper()


def read_asf(path: str | os.PathLike) -> Skeleton:
    """Parse an ASF file. Raises :class:`MocapInputError` naming the file and line."""
    raw = read_lines(path)
    lines = [(i + 1, ln.split("#", 1)[0].split()) for i, ln in enumerate(raw)]
    lines = [(i, p) for i, p in lines if p]
    err = lambda msg, line: MocapInputError(path, msg, line)
    section = None
    length_unit, angle_unit = 1.0, "deg"
    root_order: tuple[str, ...] | None = None
    root_axis = "XYZ"
    root_position = np.zeros(3)
    root_orientation = np.zeros(3)
    bones: dict[str, Bone] = {}
    children: dict[str, list[str]] = {}
    bone: dict | None = None
    in_hierarchy = hierarchy_done = False
    last_key = None
    sections_seen = set()

    def finish_bone(b: dict, line: int) -> None:
        for key in ("name", "direction", "length", "axis"):
            if key not in b:
                raise err(f"bone block without '{key}'", line)
        if b["name"] in bones or b["name"] == "root":
            raise err(f"duplicate bone name {b['name']!r}", b["name_line"])
        dofs = b.get("dof", ())
        limits = b.get("limits", [])
        if limits and len(limits) != len(dofs):
            raise err(f"bone {b['name']!r}: {len(limits)} limits for {len(dofs)} dofs", line)
        d = b["direction"]
        norm = float(np.linalg.norm(d))
        if norm < 1e-12:
            raise err(f"bone {b['name']!r}: zero direction", b["direction_line"])
        conv = math.pi / 180 if angle_unit == "deg" else 1.0
        bones[b["name"]] = Bone(
            name=b["name"],
            direction=d / norm,
            length=b["length"],
            axis=b["axis"] * conv,
            axis_order=b["axis_order"],
            dofs=tuple(dofs),
            limits=tuple((lo * conv, hi * conv) for lo, hi in limits),
        )

    for line, parts in lines:
        key = parts[0]
        if key.startswith(":"):
            if bone is not None:
                raise err(f"section {key} inside a bone block (missing 'end')", line)
            if in_hierarchy:
                raise err(f"section {key} inside the hierarchy (missing 'end')", line)
            section = key.lower()
            if section in (":root", ":bonedata", ":hierarchy", ":units") and section in sections_seen:
                raise err(f"second {key} section", line)
            sections_seen.add(section)
            continue
        if section == ":units":
            if key == "length":
                v = _floats(path, parts[1:], 1, "length unit", line)[0]
                if not 1e-6 <= v <= 1e6:
                    raise err("length unit must be between 1e-6 and 1e6", line)
                length_unit = float(v)
            elif key == "angle":
                if len(parts) != 2 or parts[1].lower() not in ("deg", "rad"):
                    raise err("angle unit must be 'deg' or 'rad'", line)
                angle_unit = parts[1].lower()
            elif key == "mass":
                _floats(path, parts[1:], 1, "mass unit", line)
            else:
                raise err(f"unknown unit {key!r}", line)
        elif section == ":root":
            if key == "order":
                order = tuple(p.upper() for p in parts[1:])
                valid = {"TX", "TY", "TZ", "RX", "RY", "RZ"}
                if not order or any(o not in valid for o in order) or len(set(order)) != len(order):
                    raise err(
                        f"root order {' '.join(parts[1:])!r} must list distinct TX TY TZ RX RY RZ", line
                    )
                root_order = order
            elif key == "axis":
                if len(parts) != 2:
                    raise err("root axis needs one order like XYZ", line)
                root_axis = _axis_order(path, parts[1], line)
            elif key == "position":
                root_position = _floats(path, parts[1:], 3, "root position", line)
            elif key == "orientation":
                root_orientation = _floats(path, parts[1:], 3, "root orientation", line)
            else:
                raise err(f"unknown root field {key!r}", line)
        elif section == ":bonedata":
            if key == "begin" and len(parts) == 1:
                if bone is not None:
                    raise err("'begin' inside a bone block", line)
                bone = {"begin": line}
                last_key = None
                continue
            if bone is None:
                raise err(f"{key!r} outside a bone block", line)
            if key == "end" and len(parts) == 1:
                finish_bone(bone, line)
                bone = None
                continue
            if key == "id":
                pass
            elif key == "name":
                if len(parts) != 2:
                    raise err("bone name must be one word", line)
                bone["name"], bone["name_line"] = parts[1], line
            elif key == "direction":
                bone["direction"] = _floats(path, parts[1:], 3, "direction", line)
                bone["direction_line"] = line
            elif key == "length":
                v = _floats(path, parts[1:], 1, "length", line)[0]
                if v < 0:
                    raise err("bone length must not be negative", line)
                bone["length"] = float(v)
            elif key == "axis":
                if len(parts) != 5:
                    raise err("axis needs three angles and an order like XYZ", line)
                bone["axis"] = _floats(path, parts[1:4], 3, "axis", line)
                bone["axis_order"] = _axis_order(path, parts[4], line)
            elif key == "dof":
                dofs = [p.lower() for p in parts[1:]]
                for d in dofs:
                    if d in ("tx", "ty", "tz", "l"):
                        raise err(f"dof {d!r} (translation/length) on a bone is not supported", line)
                    if d not in _ROT_DOFS:
                        raise err(f"unknown dof {d!r}", line)
                if len(set(dofs)) != len(dofs):
                    raise err("repeated dof", line)
                bone["dof"] = dofs
            elif key == "limits" or (key.startswith("(") and last_key == "limits"):
                text = " ".join(parts[1:] if key == "limits" else parts)
                found = _LIMIT_RE.findall(text)
                if not found or _LIMIT_RE.sub("", text).strip():
                    raise err(f"limits must be '(lo hi)' pairs, found {text!r}", line)
                pairs = bone.setdefault("limits", [])
                for lo, hi in found:
                    lo_hi = _floats(path, [lo, hi], 2, "limit", line, allow_inf=True)
                    if lo_hi[0] > lo_hi[1]:
                        raise err(f"limit ({lo} {hi}) has lower > upper", line)
                    pairs.append((float(lo_hi[0]), float(lo_hi[1])))
                key = "limits"
            elif key in ("bodymass", "cofmass"):
                _floats(path, parts[1:], 1, key, line)
            else:
                raise err(f"unknown bone field {key!r}", line)
            last_key = key
        elif section == ":hierarchy":
            if key == "begin" and len(parts) == 1 and not in_hierarchy and not hierarchy_done:
                in_hierarchy = True
                continue
            if not in_hierarchy:
                raise err(f"{key!r} outside the hierarchy's begin/end", line)
            if key == "end" and len(parts) == 1:
                in_hierarchy, hierarchy_done = False, True
                continue
            if key != "root" and key not in bones:
                raise err(f"unknown bone {key!r} in the hierarchy", line)
            for c in parts[1:]:
                if c not in bones:
                    raise err(f"unknown bone {c!r} in the hierarchy", line)
                if any(c in cs for cs in children.values()):
                    raise err(f"bone {c!r} has two parents", line)
                children.setdefault(key, []).append(c)
        elif section in (":version", ":name", ":documentation"):
            continue
        elif section is None:
            raise err(f"{key!r} before the first section", line)
        else:
            raise err(f"unknown section {section!r}", line)

    end_line = max(1, len(raw))
    if bone is not None:
        raise err("file ends inside a bone block", end_line)
    if in_hierarchy:
        raise err("file ends inside the hierarchy", end_line)
    if root_order is None:
        raise err("no ':root' section with an 'order'", end_line)
    if not bones:
        raise err("no bones", end_line)
    if not hierarchy_done:
        raise err("no complete ':hierarchy' section", end_line)
    skel = Skeleton(
        bones=bones,
        children=children,
        root_order=root_order,
        root_axis=root_axis,
        root_position=root_position,
        root_orientation=root_orientation * (math.pi / 180 if angle_unit == "deg" else 1.0),
        length_unit=length_unit,
        angle_unit=angle_unit,
        source=os.fspath(path),
    )
    order = skel.joint_order()
    if len(order) != len(set(order)):
        raise err("the hierarchy has a cycle", end_line)
    missing = [b for b in bones if b not in order]
    if missing:
        raise err(f"bones not connected to the root: {', '.join(missing)}", end_line)
    return skel


def read_amc(path: str | os.PathLike, skeleton: Skeleton) -> tuple[dict[str, np.ndarray], str]:
    """Parse an AMC file for ``skeleton``: returns ``{bone or "root": (T, n_values)}`` and the angle unit.

    Every frame must give every bone with dofs and the root exactly once (``:FULLY-SPECIFIED``), and frame
    numbers must increase by one.
    """
    raw = read_lines(path)
    err = lambda msg, line: MocapInputError(path, msg, line)
    angle_unit = skeleton.angle_unit
    counts = {"root": len(skeleton.root_order)}
    counts.update({b.name: len(b.dofs) for b in skeleton.bones.values()})
    needed = {k for k, n in counts.items() if n > 0}
    values: dict[str, list[list[float]]] = {k: [] for k in needed}
    frame_no: int | None = None
    frame_line = 0
    seen: set[str] = set()

    def close_frame(line: int) -> None:
        missing = needed - seen
        if missing:
            raise err(f"frame {frame_no} (line {frame_line}) lacks {', '.join(sorted(missing))}", line)

    started = False
    for i, text in enumerate(raw):
        line = i + 1
        parts = text.split("#", 1)[0].split()
        if not parts:
            continue
        key = parts[0]
        if key.startswith(":"):
            if started:
                raise err(f"{key} after the first frame", line)
            k = key.upper()
            if k == ":DEGREES":
                angle_unit = "deg"
            elif k == ":RADIANS":
                angle_unit = "rad"
            elif k != ":FULLY-SPECIFIED":
                raise err(f"unknown AMC keyword {key!r}", line)
            continue
        if len(parts) == 1 and _INT_RE.fullmatch(key):
            n = int(key)
            if started:
                close_frame(line)
                if n != frame_no + 1:
                    raise err(f"frame number {n} does not follow {frame_no}", line)
            started = True
            frame_no, frame_line = n, line
            seen = set()
            continue
        if not started:
            raise err(f"{key!r} before the first frame number", line)
        if key not in counts:
            raise err(f"unknown bone {key!r}", line)
        if key in seen:
            raise err(f"bone {key!r} given twice in frame {frame_no}", line)
        if counts[key] == 0 and len(parts) == 1:
            continue
        v = _floats(path, parts[1:], counts[key], f"bone {key!r}", line)
        seen.add(key)
        values[key].append(v.tolist())
    if not started:
        raise err("no frames", max(1, len(raw)))
    close_frame(len(raw))
    out = {k: np.asarray(v, dtype=np.float64).reshape(len(v), counts[k]) for k, v in values.items()}
    return out, angle_unit


def motion_from_asfamc(
    skeleton: Skeleton,
    values: dict[str, np.ndarray],
    angle_unit: str,
    *,
    fps: float,
    scale: float | None = None,
    up_axis: str = "y",
    source: str = "",
) -> Motion:
    """Build the :class:`Motion` of an ASF skeleton and its AMC values (see the module docstring)."""
    conv = math.pi / 180 if angle_unit == "deg" else 1.0
    names = skeleton.joint_order()
    index = {n: i for i, n in enumerate(names)}
    J = len(names)
    T = next(iter(values.values())).shape[0] if values else 0
    parents = [-1] + [0] * (J - 1)
    for p, cs in skeleton.children.items():
        for c in cs:
            parents[index[c]] = index[p]
    offsets = np.zeros((J, 3))
    offsets[0] = skeleton.root_position
    for j in range(1, J):
        p = parents[j]
        if p > 0:
            b = skeleton.bones[names[p]]
            offsets[j] = b.length * b.direction
    rotations = np.broadcast_to(np.eye(3), (T, J, 3, 3)).copy()
    translations = np.broadcast_to(offsets, (T, J, 3)).copy()

    root = values.get("root", np.zeros((T, 0)))
    rot_cols = [k for k, o in enumerate(skeleton.root_order) if o[0] == "R"]
    for k, o in enumerate(skeleton.root_order):
        if o[0] == "T":
            translations[:, 0, "XYZ".index(o[1])] = root[:, k]
    C = euler_to_matrix(skeleton.root_orientation[::-1], skeleton.root_axis[::-1])
    if rot_cols:
        order = "".join(skeleton.root_order[k][1] for k in rot_cols)
        M = euler_to_matrix(conv * root[:, rot_cols][:, ::-1], order[::-1])
        rotations[:, 0] = C @ M @ C.T
    for name, b in skeleton.bones.items():
        if not b.dofs:
            continue
        j = index[name]
        C = euler_to_matrix(b.axis[::-1], b.axis_order[::-1])
        order = "".join(d[1].upper() for d in b.dofs)
        M = euler_to_matrix(conv * values[name][:, ::-1], order[::-1])
        rotations[:, j] = C @ M @ C.T
    leaves = [j for j in range(1, J) if not skeleton.children.get(names[j])]
    end_offsets = np.array(
        [skeleton.bones[names[j]].length * skeleton.bones[names[j]].direction for j in leaves]
    )
    return build_motion(
        names,
        parents,
        offsets,
        rotations,
        translations,
        fps,
        source,
        leaves,
        end_offsets.reshape(-1, 3),
        scale=skeleton.scale if scale is None else scale,
        up_axis=up_axis,
    )


def load_asfamc(
    asf_path: str | os.PathLike,
    amc_path: str | os.PathLike,
    *,
    fps: float = 120.0,
    scale: float | None = None,
    up_axis: str = "y",
) -> Motion:
    """Load an ASF skeleton and an AMC motion as a :class:`Motion` in metres, z up.

    Args:
      fps: frame rate (AMC files do not record it; the CMU database was captured at 120 fps).
      scale: metres per file unit; by default ``0.0254 / f`` from the ASF ``:units length f``.
      up_axis: the file's up axis, ``"y"`` for CMU.
    """
    skel = read_asf(asf_path)
    values, unit = read_amc(amc_path, skel)
    return motion_from_asfamc(
        skel, values, unit, fps=fps, scale=scale, up_axis=up_axis, source=os.fspath(amc_path)
    )
