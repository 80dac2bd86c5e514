"""PARSEC bodytrack's tracker, a wing of the core: its body model, input files, images, cameras, likelihood,
annealing and run. The core never imports it; importing it registers with the core

* the ``parsec31`` body (:func:`jaxmocap.geometry.body.build`; millimetres, or metres with ``in_metres=True``), and
* the Bouguet ``.cal`` camera reader (:func:`jaxmocap.io.calibration.load_calibration` of a ``CALIB`` folder, a
  ``.cal`` file or a list of them, in metres).

The modules: :mod:`~jaxmocap.parsec.model` (the body), :mod:`~jaxmocap.parsec.files` (text and ``.cal`` files),
:mod:`~jaxmocap.parsec.images` (images and maps), :mod:`~jaxmocap.parsec.cameras` (cameras and projection),
:mod:`~jaxmocap.parsec.cylinders` (the fast cylinder chain), :mod:`~jaxmocap.parsec.likelihood`,
:mod:`~jaxmocap.parsec.annealing` (β rule, schedule, filter), :mod:`~jaxmocap.parsec.inputs` (sequence folders)
and :mod:`~jaxmocap.parsec.track` (the tracking run). Their public names are also reachable from the package.
The C++ code they reproduce is documented in ``jaxmocap/parsec/FORMAT.md``.
"""

from jaxmocap.geometry import body as _body
from jaxmocap.io import calibration as _calibration
from jaxmocap.parsec.cameras import Cameras, cameras_from_rig, load_cameras, project
from jaxmocap.parsec.cylinders import cylinder_corners, cylinder_poses
from jaxmocap.parsec.files import (
    DOF_NAMES,
    LENGTH_NAMES,
    LIMB_FIELDS,
    MM_PER_M,
    PART_NAMES,
    BodyShape,
    PoseParameters,
    accepts_cal,
    load_body_shape,
    load_parsec_calibration,
    load_pose,
    load_pose_parameters,
    load_poses,
)
from jaxmocap.parsec.images import edge_map, foreground_map, load_image
from jaxmocap.parsec.inputs import ParsecSequence, load_sequence
from jaxmocap.parsec.model import (
    CYLINDER_SEGMENT,
    SEGMENT_NAMES,
    cylinder_lengths,
    default_shape,
    from_metres,
    joint_positions_metres,
    parsec31,
    parsec31_in_metres,
    shape_from_dims,
    shape_to_dims,
    to_metres,
    with_limits,
)

__all__ = [
    "CYLINDER_SEGMENT",
    "DOF_NAMES",
    "LENGTH_NAMES",
    "LIMB_FIELDS",
    "MM_PER_M",
    "PART_NAMES",
    "SEGMENT_NAMES",
    "BodyShape",
    "Cameras",
    "ParsecSequence",
    "PoseParameters",
    "cameras_from_rig",
    "cylinder_corners",
    "cylinder_lengths",
    "cylinder_poses",
    "default_shape",
    "edge_map",
    "foreground_map",
    "from_metres",
    "joint_positions_metres",
    "load_body_shape",
    "load_cameras",
    "load_image",
    "load_parsec_calibration",
    "load_pose",
    "load_pose_parameters",
    "load_poses",
    "load_sequence",
    "parsec31",
    "parsec31_in_metres",
    "project",
    "shape_from_dims",
    "shape_to_dims",
    "to_metres",
    "with_limits",
]

_body.register_preset("parsec31", parsec31, parsec31_in_metres)
_calibration.register_reader("parsec", accepts_cal, load_parsec_calibration)
