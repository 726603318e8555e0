"""RGB frames of the scene from the fixed camera, with pybullet's CPU TinyRenderer.

Two ways to draw the same frame:

- :meth:`Renderer.render_full` draws the whole scene every frame (the reference, and
  the benchmarks' baseline).
- :meth:`Renderer.render` draws the static plate (floor and table) once per renderer,
  with its depth buffer, then per frame only the moving bodies (object and hand, kept
  in a second pybullet client of their own), and keeps a moving body's pixel where its
  depth is at least as near as the plate's. Its ``kind`` (:mod:`schemas.renderers`)
  says what it draws of them: ``full``, the whole viewport (dataset 3.0.0's bytes,
  equal to :meth:`Renderer.render_full` pixel for pixel), or ``window`` (the
  default, dataset 4.0.0), only the window around them that their visual shapes'
  boxes project to (:mod:`generators.window`; 1.6x cheaper, and a few pixels of ~9%
  of frames differ by a level or more from ``full``: TinyRenderer rounds a shifted
  viewport's screen coordinates differently). A window that misses the image leaves the
  plate; one that covers it all is the ``full`` draw.

Obstacles are static within an episode: a scene with obstacles draws its own plate
(floor, table, then its obstacles) once when the scene is set, in the full-scene
client, so compositing stays exact; a scene without obstacles uses the renderer's own
plate, as before. (Drawing them with the moving bodies instead would redraw every
obstacle on every frame and widen the composited window.)

Why that equals the full render pixel for pixel: TinyRenderer keeps a fragment when
its depth is at least as near as the depth buffer's, drawing bodies in creation
order; the static bodies are created first, so in a full render a pixel shows the last
moving fragment at the nearest moving depth if that depth is at least as near as the
plate's, else the plate. Depths come back as float32 values of a monotone function of
the internal depth; where a moving and a static depth are too close to order
exactly (within a few ulps), :meth:`Renderer.render` falls back to a full render for
that frame (counted in :attr:`Renderer.fallbacks`). No shadows, explicit lights.

Between two moving surfaces at exactly equal depth, the winner depends on
TinyRenderer's internal draw order, which hiding, removing or adding bodies perturbs.
A frame also depends on how often its client drew before: each draw normalises every
stored vertex normal of every body in place (``Model::normal``), which is not
idempotent in float, so shading can differ by a level between a body's first and
later draws. Nothing is ever hidden or removed, and no body outlives its episode:
every episode starts from empty clients filled in a fixed order
(:meth:`Renderer.set_scene`), and the moving-bodies client draws exactly once per
frame, so a frame's bytes depend on its episode alone, not on what the process
rendered before. (Keeping a hand loaded across episodes would save its ~18 ms of
hull building per episode, but its normals would then have been normalised by every
earlier episode's draws: measured, 1 of 252 episodes got other bytes.)

The composite touches only the window around the moving bodies: the plate is copied,
then the window's front pixels are converted, mirrored and copied with OpenCV (one
pass each). :meth:`Renderer.render_bgr` gives the same frame in OpenCV's channel order,
so the build hands it to the JPEG encoder without another conversion.

Images are mirrored left-right so that world +X is on the image's right
(:mod:`generators.camera`).

``backend="egl"`` draws full frames with pybullet's EGL OpenGL plugin instead, where
it loads (on a machine without a GPU it is Mesa's multi-threaded software
rasterizer, slower than the composited TinyRenderer). Its shading differs from
TinyRenderer's and is not reproducible across drivers, so builds use ``"tiny"``.
"""

from __future__ import annotations

import importlib.util
import numbers
from dataclasses import dataclass

import cv2
import numpy as np

from generators.bullet import p
from generators.camera import pybullet_matrices
from generators.clearance import checked_obstacles
from generators.scene import (
    build_object,
    build_obstacles,
    build_static,
    load_hand,
    set_hand_pose,
    set_object_pose,
)
from generators.window import ShapeBoxes, WindowCamera, shape_boxes, world_corners
from schemas.errors import DyanaError, SpecError
from schemas.frames import EpisodeFrames
from schemas.limits import MAX_RESOLUTION, MIN_RESOLUTION
from schemas.names import shorten
from schemas.objects import object_category
from schemas.renderers import DEFAULT_RENDERER, check_draw_kind
from schemas.scene import DEFAULT_RESOLUTION, HANDS

#: Light settings passed to every ``getCameraImage`` call (no defaults relied on).
LIGHT_DIRECTION = (0.3, 1.0, -0.5)
LIGHT_COLOR = (1.0, 1.0, 1.0)
LIGHT_DISTANCE = 10.0
LIGHT_AMBIENT = 0.55
LIGHT_DIFFUSE = 0.45
LIGHT_SPECULAR = 0.0

#: Depths within this many float32 ulps count as a tie the plate cannot settle.
TIE_ULPS = 4
#: The moving-bodies client is reset, not emptied body by body, once in this many scenes.
RESET_EVERY = 32
BACKENDS = ("tiny", "egl")


class RendererUnavailable(DyanaError):
    """The requested rendering backend cannot run on this machine."""


@dataclass(frozen=True)
class _Body:
    """A loaded moving object."""

    body: int


@dataclass(frozen=True)
class _Hand:
    """A loaded hand and its joint indices."""

    body: int
    joints: np.ndarray


def check_resolution(name: str, value: object) -> int:
    """An image side in pixels in [MIN_RESOLUTION, MAX_RESOLUTION], or SpecError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not MIN_RESOLUTION <= value <= MAX_RESOLUTION:
        raise SpecError(f"{name} must be an integer in [{MIN_RESOLUTION}, {MAX_RESOLUTION}], got {shorten(value)}")
    return int(value)


def _floats(values) -> np.ndarray | None:
    """``values`` as a float64 array, or None when they are not numbers."""
    try:
        return np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        return None


class Renderer:
    """Owns a pybullet DIRECT client holding the scene of one episode at a time (the
    static bodies, its hand, its object) and the static plate; renders (H, W, 3) uint8
    RGB frames. Use as a context manager or call :meth:`close`. ``kind`` is how it draws
    (:data:`schemas.renderers.DRAW_KINDS`)."""

    def __init__(
        self, resolution: int = DEFAULT_RESOLUTION, width: int | None = None, backend: str = "tiny",
        kind: str = DEFAULT_RENDERER,
    ):
        self.kind = check_draw_kind(kind, "kind")
        check_resolution("resolution", resolution)
        self.height = int(resolution)
        if width is not None:
            check_resolution("width", width)
        self.width = self.height if width is None else int(width)
        if backend not in BACKENDS:
            raise SpecError(f"backend must be one of {list(BACKENDS)}, got {shorten(repr(backend))}")
        self.backend = backend
        self.fallbacks = 0
        self._scenes = 0
        self._client = p.connect(p.DIRECT)
        self._full_client = p.connect(p.DIRECT)
        try:
            if backend == "egl":
                self._load_egl()
            self._setup()
        except BaseException:
            self.close()
            raise

    def _load_egl(self) -> None:
        spec = importlib.util.find_spec("eglRenderer")
        if spec is None or spec.origin is None:
            raise RendererUnavailable("pybullet's eglRenderer plugin is not installed")
        if p.loadPlugin(spec.origin, "_eglRendererPlugin", physicsClientId=self._full_client) < 0:
            raise RendererUnavailable(f"pybullet's EGL plugin {spec.origin} did not load (no EGL display?)")

    def _setup(self) -> None:
        self._view, self._proj = pybullet_matrices(self.width, self.height)
        self._camera = WindowCamera(self.width, self.height)
        self._boxes: ShapeBoxes | None = None
        self._scene: tuple = (None, None, None, ())
        self._object_pose: np.ndarray | None = None  # (7,), set by _pose when the scene has an object
        self._hand_pose: tuple[np.ndarray, np.ndarray] | None = None  # palm (6,), joints (15,), likewise
        self._hand: _Hand | None = None
        self._object: _Body | None = None
        self._full_bodies: tuple[_Hand | None, _Body | None] | None = None
        self._full_static = False  # the full-scene client holds exactly the static bodies and obstacles
        p.resetSimulation(physicsClientId=self._full_client)
        build_static(self._full_client)
        self._bare_plate = self._plate_from(self._full_client)
        self._use_plate(self._bare_plate)
        _, empty = self._draw(self._client)
        self._empty_depth = float(empty.min())

    def _plate_from(self, client: int) -> tuple[np.ndarray, ...]:
        """The static plate drawn in ``client``: depth, mirrored RGB, mirrored BGR and depth
        tie widths."""
        rgba, depth = self._draw(client)
        rgb = np.ascontiguousarray(rgba[:, ::-1, :3])
        return depth, rgb, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), TIE_ULPS * np.spacing(depth)

    def _use_plate(self, plate: tuple[np.ndarray, ...]) -> None:
        self._plate_depth, self._plate_rgb, self._plate_bgr, self._tie = plate

    def _add_moving(self, client: int) -> tuple[_Hand | None, _Body | None]:
        """Create the episode's hand, then its object, in ``client``."""
        name, size, hand, _ = self._scene
        hand_body: _Hand | None = None
        object_body: _Body | None = None
        if hand is not None:
            body, indices = load_hand(client, hand)
            hand_body = _Hand(body, indices)
        if name is not None:
            body = build_object(client, name, size)
            object_body = _Body(body)
        return hand_body, object_body

    def _build(self) -> None:
        """Empty the moving-bodies client and create the episode's hand and object in it.

        TinyRenderer's frames depend on its draw order and on each body's draw count
        (see the module docstring). So nothing is ever hidden and no body outlives its
        episode: each episode starts from an empty client with fresh bodies created in a
        fixed order, which makes every frame a function of its episode alone, whatever
        the process rendered before (1 or 2 workers, a replay). The client is emptied by
        removing its two bodies, which leaves TinyRenderer's table of shapes empty as a
        reset does, but keeps pybullet's cache of the hand's GUI shapes
        (:func:`generators.scene.load_hand`: 8 ms an episode); every
        :data:`RESET_EVERY` scenes it is reset instead, which frees the ~50 KB that each
        cached load leaves behind (measured). The full-scene client
        (static bodies, the obstacles, then the same hand and object) is reset and
        filled only when a frame needs it; with obstacles, its static part is built at
        once to draw the scene's plate, and the hand and object are added when a frame
        needs them.
        """
        self._scenes += 1
        if self._scenes % RESET_EVERY == 0:
            p.resetSimulation(physicsClientId=self._client)
        else:
            for body in (self._object, self._hand):
                if body is not None:
                    p.removeBody(body.body, physicsClientId=self._client)
        self._hand, self._object = self._add_moving(self._client)
        moving = tuple(b.body for b in (self._hand, self._object) if b is not None)
        self._boxes = shape_boxes(self._client, moving) if moving else None
        self._full_bodies = None
        self._full_static = False
        if not self._scene[3]:
            self._use_plate(self._bare_plate)
            return
        self._build_full_static()
        if self.backend == "tiny":
            self._use_plate(self._plate_from(self._full_client))

    def _build_full_static(self) -> None:
        c = self._full_client
        p.resetSimulation(physicsClientId=c)
        build_static(c)
        build_obstacles(c, self._scene[3])
        self._full_static = True

    def _full_scene(self) -> tuple[_Hand | None, _Body | None]:
        if self._full_bodies is None:
            if not self._full_static:
                self._build_full_static()
            self._full_bodies = self._add_moving(self._full_client)
            self._full_static = False
        return self._full_bodies

    # lifecycle ---------------------------------------------------------------
    def close(self) -> None:
        for name in ("_client", "_full_client"):
            client = getattr(self, name, None)
            if client is not None:
                p.disconnect(client)
                setattr(self, name, None)

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # scene -------------------------------------------------------------------
    def set_scene(
        self, object_name: str | None, object_size: float | None, hand: str | None, obstacles=()
    ) -> None:
        """Choose the object (category and size; None for none), the hand (side; None
        for none) and the obstacles (:class:`schemas.obstacles.Obstacle`, drawn in order)
        that the following frames show. A different scene is rebuilt from empty clients
        (see :meth:`_build`); the same scene again is kept as it is, which is equivalent,
        since posing bodies never changes TinyRenderer's draw order."""
        if object_name is not None:
            if not isinstance(object_name, str):
                raise SpecError(f"object must be a category name or None, got {shorten(repr(object_name))}")
            object_category(object_name)
            if (
                isinstance(object_size, (bool, np.bool_))
                or not isinstance(object_size, numbers.Real)
                or not np.isfinite(object_size)
                or object_size <= 0
            ):
                raise SpecError(f"object_size must be a finite number > 0, got {shorten(repr(object_size))}")
            object_size = float(object_size)
        else:
            object_size = None
        if hand is not None and (not isinstance(hand, str) or hand not in HANDS):
            raise SpecError(f"hand must be one of {list(HANDS)} or None, got {shorten(repr(hand))}")
        scene = (object_name, object_size, hand, checked_obstacles(obstacles))
        if scene == self._scene:
            return
        self._scene = scene
        self._build()

    def _pose(self, object_pose, palm_pose, joint_angles) -> None:
        pose = palm = joints = None
        if self._object is not None:
            pose = _floats(object_pose)
            if pose is None or pose.shape != (7,) or not np.all(np.isfinite(pose)):
                raise SpecError(f"object_pose must be 7 finite numbers, got {shorten(repr(object_pose))}")
        if self._hand is not None:
            palm, joints = _floats(palm_pose), _floats(joint_angles)
            if (
                palm is None
                or joints is None
                or palm.shape != (6,)
                or joints.shape != (15,)
                or not (np.all(np.isfinite(palm)) and np.all(np.isfinite(joints)))
            ):
                raise SpecError(f"palm_pose (6,) and joint_angles (15,) must be finite numbers, "
                              f"got {shorten(repr(palm_pose))}, {shorten(repr(joint_angles))}")
        self._object_pose = pose
        self._hand_pose = None if palm is None or joints is None else (palm, joints)
        self._apply(self._client, self._hand, self._object)

    def _apply(self, client: int, hand: _Hand | None, obj: _Body | None) -> None:
        if obj is not None and self._object_pose is not None:
            set_object_pose(client, obj.body, self._object_pose)
        if hand is not None and self._hand_pose is not None:
            set_hand_pose(client, hand.body, hand.joints, *self._hand_pose)

    # drawing -----------------------------------------------------------------
    def _draw(
        self, client: int, projection: list[float] | None = None, width: int | None = None, height: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """One TinyRenderer pass over whatever is in view: (H, W, 4) RGBA and (H, W) depth,
        unmirrored. (Kept as RGBA: OpenCV converts that in one pass, while any copy of its
        three-of-four-channel view runs element by element, ~40x slower.) Another
        ``projection`` and viewport size draw a window (:mod:`generators.window`)."""
        width, height = width or self.width, height or self.height
        _, _, rgba, depth, _ = p.getCameraImage(
            width,
            height,
            viewMatrix=self._view,
            projectionMatrix=self._proj if projection is None else projection,
            lightDirection=LIGHT_DIRECTION,
            lightColor=LIGHT_COLOR,
            lightDistance=LIGHT_DISTANCE,
            shadow=0,
            lightAmbientCoeff=LIGHT_AMBIENT,
            lightDiffuseCoeff=LIGHT_DIFFUSE,
            lightSpecularCoeff=LIGHT_SPECULAR,
            renderer=p.ER_TINY_RENDERER if self.backend == "tiny" else p.ER_BULLET_HARDWARE_OPENGL,
            flags=p.ER_NO_SEGMENTATION_MASK,
            physicsClientId=client,
        )
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)
        depth = np.asarray(depth, dtype=np.float32).reshape(height, width)
        return rgba, depth

    def _full(self, bgr: bool = False) -> np.ndarray:
        hand, obj = self._full_scene()
        self._apply(self._full_client, hand, obj)
        rgba, _ = self._draw(self._full_client)
        return cv2.flip(cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGR if bgr else cv2.COLOR_RGBA2RGB), 1)

    def render_full(self, object_pose=None, palm_pose=None, joint_angles=None) -> np.ndarray:
        """The naive frame: the whole scene drawn by TinyRenderer. (H, W, 3) uint8 RGB."""
        self._pose(object_pose, palm_pose, joint_angles)
        return self._full()

    def render(self, object_pose=None, palm_pose=None, joint_angles=None) -> np.ndarray:
        """The frame for these states, composited over the static plate (with the ``full``
        kind, equal to :meth:`render_full` pixel for pixel). (H, W, 3) uint8 RGB."""
        return self._frame(object_pose, palm_pose, joint_angles, bgr=False)

    def render_bgr(self, object_pose=None, palm_pose=None, joint_angles=None) -> np.ndarray:
        """The frame of :meth:`render` with its channels in OpenCV's order: (H, W, 3) uint8
        BGR, for :func:`generators.encode.encode_bgr_jpeg`."""
        return self._frame(object_pose, palm_pose, joint_angles, bgr=True)

    def _frame(self, object_pose, palm_pose, joint_angles, bgr: bool) -> np.ndarray:
        self._pose(object_pose, palm_pose, joint_angles)
        if self.backend != "tiny":
            return self._full(bgr)
        if self._object is None and self._hand is None:
            return self._plate(bgr).copy()
        if self.kind == "full":
            return self._composite(*self._draw(self._client), bgr)
        window = self.window()
        if window is None:
            return self._plate(bgr).copy()
        r0, r1, c0, c1 = window
        rgba, depth = self._draw(self._client, self._camera.projection(window), c1 - c0, r1 - r0)
        return self._composite(rgba, depth, bgr, r0, c0)

    def _plate(self, bgr: bool) -> np.ndarray:
        """The static plate in the frame's channel order (read only: copy before drawing on it)."""
        return self._plate_bgr if bgr else self._plate_rgb

    def window(self) -> tuple[int, int, int, int] | None:
        """The window ``(r0, r1, c0, c1)`` of the unmirrored image that the ``window``
        renderer draws for the posed moving bodies (:mod:`generators.window`), None when
        they are out of view; the whole image for a shape without a box."""
        if self._boxes is None:
            return None if self._object is None and self._hand is None else (0, self.height, 0, self.width)
        return self._camera.window(world_corners(self._boxes))

    def _composite(self, rgba: np.ndarray, depth: np.ndarray, bgr: bool, top: int = 0, left: int = 0) -> np.ndarray:
        """The moving bodies' draw (of the unmirrored image's window at ``top``, ``left``)
        over the plate: a moving pixel shows where its depth is at least as near as the
        plate's; a near-tie falls back to a full render."""
        plate = self._plate(bgr)
        # OpenCV's one-pass calls on the window (each numpy expression is a pass and an array):
        # the bounds of the drawn pixels, then the near-tie test and the front mask on them.
        moving = (depth < self._empty_depth).view(np.uint8)
        c0, r0, width, height = cv2.boundingRect(moving)  # a uint8 array is a mask: its nonzero pixels
        if width == 0:
            return plate.copy()
        r1, c1 = r0 + height, c0 + width
        at = np.s_[r0 + top : r1 + top, c0 + left : c1 + left]
        inside, near, far = moving[r0:r1, c0:c1], depth[r0:r1, c0:c1], self._plate_depth[at]
        tied = cv2.compare(cv2.absdiff(near, far), self._tie[at], cv2.CMP_LE)  # |near - far| <= tie, exactly
        if cv2.countNonZero(cv2.bitwise_and(tied, inside)):
            self.fallbacks += 1
            return self._full(bgr)
        front = cv2.flip(cv2.bitwise_and(cv2.compare(near, far, cv2.CMP_LE), inside), 1)
        pixels = cv2.flip(cv2.cvtColor(rgba[r0:r1, c0:c1], cv2.COLOR_RGBA2BGR if bgr else cv2.COLOR_RGBA2RGB), 1)
        out = plate.copy()
        cv2.copyTo(pixels, front, out[r0 + top : r1 + top, self.width - c1 - left : self.width - c0 - left])
        return out

    def object_pixels(self, object_pose, palm_pose, joint_angles) -> tuple[int, int]:
        """The object's pixels in TinyRenderer's segmentation mask: ``(shown, alone)``,
        with the hand posed as given (and the scene's obstacles in place), then alone:
        with the hand moved out of view and no obstacles. Their ratio is the visible
        fraction :mod:`generators.visibility` computes analytically."""
        if self._object is None or self._hand is None:
            raise SpecError("object_pixels needs a scene with an object and a hand (set_scene)")
        self._pose(object_pose, palm_pose, joint_angles)
        if self._hand_pose is None:
            raise SpecError("object_pixels needs the hand posed (palm_pose and joint_angles)")
        if self._scene[3]:
            hand, obj = self._full_scene()
            if obj is None:  # the full scene holds the same object as self._object
                raise SpecError("object_pixels needs a scene with an object (set_scene)")
            self._apply(self._full_client, hand, obj)
            shown = self._object_mask(self._full_client, obj)
        else:
            shown = self._object_mask(self._client, self._object)
        away = np.array([0.0, -1000.0, 0.0, 0.0, 0.0, 0.0])
        set_hand_pose(self._client, self._hand.body, self._hand.joints, away, self._hand_pose[1])
        alone = self._object_mask(self._client, self._object)
        self._apply(self._client, self._hand, self._object)
        return int(shown.sum()), int(alone.sum())

    def _object_mask(self, client: int, obj: _Body) -> np.ndarray:
        _, _, _, _, seg = p.getCameraImage(
            self.width,
            self.height,
            viewMatrix=self._view,
            projectionMatrix=self._proj,
            shadow=0,
            renderer=p.ER_TINY_RENDERER,
            physicsClientId=client,
        )
        return np.asarray(seg, dtype=np.int64).reshape(self.height, self.width) == obj.body

    def render_episode(
        self,
        frames: EpisodeFrames,
        object_name: str,
        object_size: float,
        hand: str,
        full: bool = False,
        obstacles=(),
        bgr: bool = False,
    ) -> list[np.ndarray]:
        """All frames of one episode among ``obstacles`` (pass the spec's); ``full`` draws
        each with :meth:`render_full`, ``bgr`` (composited only) with :meth:`render_bgr`."""
        self.set_scene(object_name, object_size, hand, obstacles)
        draw = self.render_full if full else self.render_bgr if bgr else self.render
        return [
            draw(frames.object_pose[i], frames.palm_pose[i], frames.joint_angles[i]) for i in range(frames.num_frames)
        ]
