"""`pipeline view`: one recorded episode as a rerun recording (.rrd).

Logs the camera image, the object's and the palm's trajectories, the keypoints and the
hand skeleton, the phase, the palm/fingertip distances and the action over two
timelines (``frame`` and ``time``), read from the shards alone.

Axes: Dyana's world is left-handed (X right, Y up, Z forward) and rerun's 3D view is
right-handed, so every 3D thing is logged in the MCAP shard's ``world`` frame
(:mod:`catalog.tables.mcap_layout`): ``x = Dyana x`` (right), ``y = Dyana z`` (forward), ``z = Dyana y``
(up), declared as ``rr.ViewCoordinates.RFU``; positions swap y and z, rotation quaternions
``(qx, qy, qz, qw)`` become ``(-qx, -qz, -qy, qw)``. Logged as is, the scene would be the
mirror image of what the camera shows. The camera is logged at ``world/camera`` (its pose
and pinhole, as in the MCAP's ``/tf`` and ``/camera/calibration``) with the image under it,
so rerun shows the image inside the 3D view and the 3D things over the image.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa

from catalog.store.manifest import Manifest
from catalog.store.outputs import DESCRIPTOR_ALIAS, check_output, staged_output
from catalog.store.storage import as_location
from catalog.tables.mcap_layout import camera_calibration, camera_pose, to_foxglove_position, to_foxglove_quaternion
from catalog.tables.parquet_io import column_to_numpy
from catalog.tables.reader import open_folder
from schemas.errors import DyanaError, OutputError, SpecError
from schemas.names import shorten
from schemas.scene import LOC_TOLERANCE, PHASES
from schemas.spec import EpisodeSpec
from schemas.tables import OBSTACLE_CLEARANCE

if TYPE_CHECKING:  # rerun is imported when a recording is written (it starts a Rust runtime)
    from rerun import RecordingStream

#: Phase colours (observe, approach, grasp, hold) for the palm trail and text log.
PHASE_COLOURS = {"observe": (150, 150, 150), "approach": (40, 120, 255), "grasp": (255, 140, 0), "hold": (40, 200, 80)}
OBJECT_COLOUR = (230, 60, 60)


def _episode_rows(directory: Path, episode: int) -> tuple[Manifest, pa.Table, dict[str, Any]]:
    """The folder's manifest, one episode's frames and its row, read through the checked
    reader (sizes and sha256 of the shard read, settings, numbering)."""
    folder = open_folder(directory, verify="sha256")
    row, rows = folder.episode(episode)
    return folder.manifest, rows, row


def _skeleton(joint_poses: np.ndarray, keypoints: np.ndarray) -> list[np.ndarray]:
    """Per finger: wrist, its three joints, its fingertip; plus the palm's knuckle line."""
    joints = joint_poses.reshape(5, 3, 6)[:, :, :3]
    tips = keypoints.reshape(6, 6)[:5, :3]
    wrist = keypoints.reshape(6, 6)[5, :3]
    strips = [np.vstack([wrist, joints[f], tips[f]]) for f in range(5)]
    strips.append(joints[:, 0, :])
    return strips


#: Seconds rerun may take to write a recording out (it is a few MB; a stall means a full disk).
FLUSH_TIMEOUT_S = 60.0


def check_writable(out: Path) -> None:
    """OutputError naming the folder when no file can be made beside ``out`` (its nearest
    existing folder): found before any work, not by rerun's writer after it. A device, a
    FIFO or a descriptor alias (``/dev/stdout``) is written in place: nothing to check."""
    if DESCRIPTOR_ALIAS.match(os.path.abspath(out)) or (out.exists() and not out.is_file()):
        return
    folder = Path(os.path.realpath(out)).parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        handle, probe = tempfile.mkstemp(dir=folder, prefix=".dyana-probe-")
    except OSError as exc:
        raise OutputError(f"--out: cannot write into the folder {shorten(repr(str(folder)))} "
                          f"({exc.strerror or exc})") from None
    os.close(handle)
    os.unlink(probe)


def write_recording(directory: str | Path, episode: int, out: str | Path) -> Path:
    """Write episode ``episode`` of a slice or rollout folder to ``out`` (.rrd).

    A write that fails (a full disk) leaves no file and is one DyanaError naming ``out``;
    rerun's own log lines are kept off the terminal (``RUST_LOG``, unless the user set it)."""
    if isinstance(episode, bool) or not isinstance(episode, (int, np.integer)):
        raise SpecError(f"--episode must be an integer, got {shorten(repr(episode))}")
    as_location(out, "out")  # a name (str or path-like), before check_output looks at it
    check_output(out, [], "--out")  # the name as given: Path() would turn a URL into a local "s3:" folder
    directory, out = as_location(directory, "directory"), Path(out)
    if out.suffix != ".rrd":
        raise SpecError(f"--out must end in .rrd, got {str(out)!r}")
    check_output(out, [directory], "--out")  # never over a device or a file of the folder read
    check_writable(out)
    os.environ.setdefault("RUST_LOG", "off")
    import rerun as rr  # after the checks: a bad argument costs no rerun import
    manifest, rows, meta = _episode_rows(directory, episode)
    columns = EpisodeColumns.of(rows)
    images = columns.images

    out.parent.mkdir(parents=True, exist_ok=True)
    if out.is_dir():
        raise SpecError(f"--out {str(out)!r} is a folder, give a file name ending in .rrd")
    needed = 2 * sum(len(image) for image in images) + 4096 * len(images) + (64 << 10)
    free = shutil.disk_usage(out.parent).free
    if free < needed:  # rerun's writer can stall on a full disk, so refuse before writing
        raise DyanaError(f"{out}: not enough free space for the recording (about {needed:,} bytes, {free:,} free)")
    with staged_output(out, [directory], "--out") as temp:
        rec = rr.RecordingStream("dyana", recording_id=meta["spec_hash"])
        try:
            try:
                rec.save(str(temp))
            except RuntimeError as exc:  # rerun cannot create the file (the folder changed since the check)
                raise DyanaError(f"{out}: cannot write the recording ({shorten(str(exc), 200)})") from None
            _log_episode(rec, rows, meta, columns, dict(manifest.settings))
        except BaseException:
            with contextlib.suppress(RuntimeError):
                rec.disconnect()
            raise
        try:
            rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
            rec.disconnect()
        except RuntimeError as exc:  # rerun's file writer failed or stalled (a full disk, an unwritable folder)
            raise DyanaError(f"{out}: cannot write the recording ({shorten(str(exc), 200)})") from None
    return out


#: Entity paths of the camera (pose and pinhole) and of its image.
CAMERA_ENTITY = "world/camera"
IMAGE_ENTITY = f"{CAMERA_ENTITY}/image"


def to_view(xyz: np.ndarray) -> np.ndarray:
    """Dyana positions (..., 3) -> the recording's right-handed world (x, z, y), as float32."""
    return to_foxglove_position(xyz).astype(np.float32)


def _log_camera(rec: RecordingStream, resolution: int) -> None:
    """The fixed camera: its optical frame (x right, y down, z forward) in the world and its
    pinhole for a ``resolution``-pixel square image."""
    import rerun as rr

    eye, rotation = camera_pose()
    rec.log(CAMERA_ENTITY, rr.Transform3D(translation=eye, quaternion=rr.Quaternion(xyzw=rotation)), static=True)
    k = np.array(camera_calibration(resolution, resolution)["K"], dtype=np.float64).reshape(3, 3)
    rec.log(CAMERA_ENTITY, rr.Pinhole(image_from_camera=k, resolution=[resolution, resolution],
                                      camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=1.0), static=True)


@dataclass(frozen=True)
class EpisodeColumns:
    """The columns of one episode's frames that the recording shows."""

    images: list[bytes]
    phases: list[str]
    timestamps: np.ndarray
    frame_index: np.ndarray
    state: dict[str, np.ndarray]
    fingertip: np.ndarray
    palm_xz: np.ndarray

    @classmethod
    def of(cls, rows: pa.Table) -> EpisodeColumns:
        state = {name: column_to_numpy(rows.column(name)) for name in
                 ("object_pose", "palm_pose", "joint_poses", "keypoints", "action", "joint_angles")}
        return cls(
            images=rows.column("image").to_pylist(),
            phases=rows.column("phase").to_pylist(),
            timestamps=rows.column("timestamp").to_numpy(),
            frame_index=rows.column("frame_index").to_numpy(),
            state=state,
            fingertip=rows.column("fingertip_distance").to_numpy(),
            palm_xz=np.linalg.norm(state["palm_pose"][:, [0, 2]] - state["object_pose"][:, [0, 2]], axis=1),
        )


def _log_episode(rec: RecordingStream, rows: pa.Table, meta: dict[str, Any], columns: EpisodeColumns,
                 settings: dict[str, Any]) -> None:
    import rerun as rr

    images, phases, timestamps, frame_index = columns.images, columns.phases, columns.timestamps, columns.frame_index
    state, fingertip, palm_xz = columns.state, columns.fingertip, columns.palm_xz

    rec.log("world", rr.ViewCoordinates.RFU, static=True)
    resolution = settings.get("resolution")
    if isinstance(resolution, int) and not isinstance(resolution, bool) and resolution > 0:
        _log_camera(rec, resolution)
    media_type = "image/png" if settings.get("image_format") == "png" else "image/jpeg"
    title = f"{meta['episode_id']}: {meta['motion_type']} {meta['intercept_setting']}, {meta['object']}, {meta['hand']} hand"
    rec.log("episode", rr.TextDocument(f"{title}\n\n{meta['text']}\n\npolicy: {meta.get('policy', 'ground truth')}"),
            static=True)
    object_xyz = to_view(state["object_pose"][:, :3])
    palm_xyz = to_view(state["palm_pose"][:, :3])
    target_xyz = to_view(state["action"][:, :3])
    keypoints_xyz = to_view(state["keypoints"].reshape(-1, 6, 6)[:, :, :3])
    rec.log("world/object/path", rr.LineStrips3D([object_xyz], colors=[OBJECT_COLOUR], radii=0.02), static=True)
    rec.log("world/palm/path", rr.LineStrips3D([palm_xyz], colors=[(40, 120, 255)], radii=0.02), static=True)
    obstacles = EpisodeSpec.from_json(meta["spec"]).obstacles if "spec" in meta else ()
    if obstacles:
        rec.log("world/obstacles", rr.Boxes3D(
            centers=[to_view(np.array(o.position)) for o in obstacles],
            half_sizes=[to_view(np.array(o.half_extents)) for o in obstacles],
            quaternions=[rr.Quaternion(xyzw=to_foxglove_quaternion(np.array(o.quaternion))) for o in obstacles],
            colors=[tuple(int(round(255 * c)) for c in o.rgba) for o in obstacles],
            labels=[o.category for o in obstacles],
        ), static=True)
    clearance = rows.column(OBSTACLE_CLEARANCE).to_numpy() if OBSTACLE_CLEARANCE in rows.column_names else None
    previous_phase = None
    for k, image in enumerate(images):
        rec.set_time("frame", sequence=int(frame_index[k]))
        rec.set_time("time", duration=float(timestamps[k]))
        phase = phases[k]
        colour = PHASE_COLOURS.get(phase, (255, 255, 255))
        rec.log(IMAGE_ENTITY, rr.EncodedImage(contents=image, media_type=media_type))
        rec.log("world/object/centre", rr.Points3D([object_xyz[k]], colors=[OBJECT_COLOUR], radii=0.08))
        rec.log("world/palm/centre", rr.Points3D([palm_xyz[k]], colors=[colour], radii=0.08))
        rec.log("world/palm/target", rr.Points3D([target_xyz[k]], colors=[(255, 255, 255)], radii=0.04))
        rec.log("world/hand/keypoints", rr.Points3D(keypoints_xyz[k], radii=0.04,
                                                   labels=["thumb", "index", "middle", "ring", "little", "wrist"]))
        rec.log("world/hand/skeleton", rr.LineStrips3D(
            [to_view(strip) for strip in _skeleton(state["joint_poses"][k], state["keypoints"][k])],
            colors=[colour], radii=0.015))
        rec.log("distance/palm_xz", rr.Scalars(float(palm_xz[k])))
        rec.log("distance/tolerance", rr.Scalars(LOC_TOLERANCE))
        rec.log("distance/fingertip", rr.Scalars(float(fingertip[k])))
        if obstacles and clearance is not None:
            rec.log("distance/obstacle_clearance", rr.Scalars(float(clearance[k])))
        rec.log("phase/index", rr.Scalars(float(PHASES.index(phase)) if phase in PHASES else -1.0))
        rec.log("hand/joint_angle_mean", rr.Scalars(float(state["joint_angles"][k].mean())))
        if phase != previous_phase:
            rec.log("phase/log", rr.TextLog(f"frame {int(frame_index[k])}: {phase}", color=colour))
            previous_phase = phase
