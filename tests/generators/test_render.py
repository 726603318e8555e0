"""The renderer (the ``full`` kind: tests/generators/test_render_window.py has ``window``):
composited frames equal full renders pixel for pixel (obstacles
included), frames show what the states say, determinism, JPEG encoding."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from generators.camera import project
from generators.encode import JPEG_QUALITY, decode_jpeg, encode_jpeg
from generators.hand import JOINT_LOWER, JOINT_UPPER, REST_JOINTS, REST_PALM
from generators.hand_urdf import PALM_SKIN
from generators.render import Renderer, RendererUnavailable
from generators.scene import MARKING_RGBA, TABLE_RGBA, TABLE_TOP_GAP
from schemas.errors import ShardError, SpecError
from schemas.frames import EpisodeFrames
from schemas.objects import OBJECTS
from schemas.obstacles import OBSTACLE_CATEGORIES, Obstacle
from schemas.scene import WORKSPACE_X, WORKSPACE_Z
from tests.generators.colours import colour_mask, matches

SMALL = 96
FULL = 224
IDENTITY = [0.0, 0.0, 0.0, 1.0]


def fraction(window: np.ndarray, rgba) -> float:
    return float(colour_mask(window, rgba).mean())


def resting(name: str, x: float, z: float, size: float | None = None, quat=IDENTITY) -> tuple[float, np.ndarray]:
    cat = OBJECTS[name]
    size = cat.nominal_size if size is None else size
    return size, np.array([x, cat.half_height(size), z, *quat])


def pixel_of(point, resolution: int) -> tuple[int, int]:
    (col, row), _ = project(np.asarray(point, dtype=np.float64), resolution, resolution)
    return int(row), int(col)


def random_quat(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


@pytest.fixture(scope="module")
def small():
    with Renderer(SMALL, kind="full") as renderer:
        yield renderer


@pytest.fixture(scope="module")
def full():
    with Renderer(FULL, kind="full") as renderer:
        yield renderer


def random_states(rng: np.random.Generator, n: int):
    """Objects anywhere in the workspace (corners included), hands near objects and
    down to the table (fingers may dip into it), random orientations and joints."""
    names = sorted(OBJECTS)
    corners = [(x, z) for x in WORKSPACE_X for z in WORKSPACE_Z]
    for i in range(n):
        name = names[i % len(names)]
        cat = OBJECTS[name]
        size = cat.nominal_size * rng.uniform(0.7, 1.3)
        x, z = corners[i % 4] if i % 3 == 0 else (rng.uniform(*WORKSPACE_X), rng.uniform(*WORKSPACE_Z))
        quat = random_quat(rng) if i % 2 else IDENTITY
        pose = np.array([x, cat.half_height(size), z, *quat])
        palm = np.array(
            [
                x + rng.normal(0, 0.4),
                rng.uniform(0.1, 3.0),
                z + rng.normal(0, 0.4),
                rng.normal(0, 0.3),
                rng.normal(0, 0.3),
                rng.normal(0, 0.6),
            ]
        )
        joints = rng.uniform(JOINT_LOWER, JOINT_UPPER)
        yield name, size, ("right", "left")[i % 2], pose, palm, joints


@pytest.mark.slow(cover="tests/generators/test_render.py::test_composited_equals_full_render_at_224")
def test_composited_equals_full_render_pixel_for_pixel(small):
    """200 random scenes (20 s); the default run keeps 40 at 224 px and 60 among obstacles below."""
    rng = np.random.default_rng(7)
    for name, size, side, pose, palm, joints in random_states(rng, 200):
        small.set_scene(name, size, side)
        fast = small.render(pose, palm, joints)
        reference = small.render_full(pose, palm, joints)
        assert fast.shape == (SMALL, SMALL, 3) and fast.dtype == np.uint8
        diff = np.argwhere((fast != reference).any(axis=2))
        assert diff.size == 0, f"{name} {side} pose={pose} palm={palm}: {len(diff)} pixels differ, e.g. {diff[:3]}"


def test_composited_equals_full_render_at_224(full):
    rng = np.random.default_rng(11)
    for name, size, side, pose, palm, joints in random_states(rng, 40):
        full.set_scene(name, size, side)
        assert np.array_equal(full.render(pose, palm, joints), full.render_full(pose, palm, joints)), name


def test_the_hand_alone_and_nothing_equal_full_renders(small):
    small.set_scene(None, None, "left")
    palm = np.array([1.0, 0.25, 3.0, 0.2, -0.1, 0.4])
    assert np.array_equal(small.render(None, palm, JOINT_UPPER), small.render_full(None, palm, JOINT_UPPER))
    small.set_scene(None, None, None)
    assert np.array_equal(small.render(), small.render_full())


def test_depth_ties_fall_back_to_a_full_render(small):
    """A box whose top face lies in the table's top plane ties in depth with the plate
    everywhere on it: the renderer must notice and still return the full render."""
    cat = OBJECTS["toy_cube"]
    size = cat.nominal_size
    hy = cat.scaled_dims(size)[1]
    pose = np.array([0.0, -TABLE_TOP_GAP - hy, 4.0, *IDENTITY])
    small.set_scene("toy_cube", size, None)
    before = small.fallbacks
    fast = small.render(pose)
    assert small.fallbacks == before + 1
    assert np.array_equal(fast, small.render_full(pose))


def test_object_centre_shows_the_object_colour(full):
    for name in ("tennis_ball", "soda_can", "mug", "cracker_box"):
        cat = OBJECTS[name]
        for x, z in ((WORKSPACE_X[0], WORKSPACE_Z[0]), (0.0, 4.5), (WORKSPACE_X[1], WORKSPACE_Z[1])):
            size, pose = resting(name, x, z)
            full.set_scene(name, size, None)
            img = full.render(pose)
            row, col = pixel_of(pose[:3], FULL)
            assert matches(img[row, col], cat.rgba) or matches(img[row, col], MARKING_RGBA[name]), (name, x, z)
            assert fraction(img[row - 2 : row + 3, col - 2 : col + 3], cat.rgba) >= 0.4, (name, x, z)
            assert not matches(img[row, col], TABLE_RGBA)


def test_the_resting_hand_shows_its_fingers_at_the_bottom_edge(full):
    """At rest the palm sits at the image's bottom edge and the fingers reach into it."""
    from generators.hand import fingertip_positions
    from generators.hand_urdf import NAIL, SKIN

    full.set_scene("orange", OBJECTS["orange"].nominal_size, "right")
    _, pose = resting("orange", 0.0, 7.0)
    img = full.render(pose, REST_PALM, REST_JOINTS)
    assert pixel_of(REST_PALM[:3], FULL)[0] >= FULL - 1
    for tip in fingertip_positions(REST_PALM[None], REST_JOINTS[None], "right")[0, 1:4]:
        row, col = pixel_of(tip, FULL)
        assert matches(img[row, col], NAIL) or matches(img[row, col], SKIN), (tip, img[row, col])


def test_palm_centre_shows_the_palm(full):
    full.set_scene("orange", OBJECTS["orange"].nominal_size, "right")
    for palm in (np.array([0.0, 1.65, 0.5, 0.0, 0.0, 0.0]), np.array([-2.0, 1.5, 3.0, 0.0, 0.0, 0.3]), np.array([2.5, 1.0, 6.5, 0.1, 0.0, -0.4])):
        _, pose = resting("orange", 0.0, 7.0)
        img = full.render(pose, palm, REST_JOINTS)
        row, col = pixel_of(palm[:3], FULL)
        assert matches(img[row, col], PALM_SKIN), (palm, img[row, col])
        assert not matches(img[row, col], TABLE_RGBA)


def test_world_left_is_image_left(full):
    name = "water_bottle"
    cat = OBJECTS[name]
    for x, left in ((WORKSPACE_X[0], True), (WORKSPACE_X[1], False)):
        size, pose = resting(name, x, 4.0)
        full.set_scene(name, size, None)
        img = full.render(pose)
        mask = colour_mask(img, cat.rgba)
        cols = np.nonzero(mask)[1]
        assert cols.size > 20
        assert (cols.mean() < FULL / 2) == left


def test_every_category_renders_its_colour(full):
    full.set_scene(None, None, None)
    plate = full.render()
    for name, cat in sorted(OBJECTS.items()):
        size, pose = resting(name, 0.5, 3.5)
        full.set_scene(name, size, "left")
        img = full.render(pose, np.array([-2.5, 2.0, 1.0, 0, 0, 0]), REST_JOINTS)
        row, col = pixel_of(pose[:3], FULL)
        window = img[row - 6 : row + 7, col - 6 : col + 7]
        assert fraction(window, cat.rgba) >= 0.25, name
        changed = (img != plate).any(axis=2)
        assert changed[row - 6 : row + 7, col - 6 : col + 7].mean() >= 0.25, name


def test_same_states_give_the_same_bytes_across_renderers(small):
    rng = np.random.default_rng(3)
    states = list(random_states(rng, 6))
    first = []
    for name, size, side, pose, palm, joints in states:
        small.set_scene(name, size, side)
        first.append(small.render(pose, palm, joints).tobytes())
    again = []
    with Renderer(SMALL, kind="full") as other:
        for name, size, side, pose, palm, joints in reversed(states):
            other.set_scene(name, size, side)
            again.append(other.render(pose, palm, joints).tobytes())
            assert other.render(pose, palm, joints).tobytes() == again[-1]
    assert first == again[::-1]


OBSTACLES = (
    Obstacle("crate", (-1.5, 4.0), (0.6, 0.5, 0.6), 0.3),
    Obstacle("book", (2.0, 5.5), (0.75, 0.15, 0.55), -0.5),
    Obstacle("brick", (0.6, 3.0), (0.55, 0.28, 0.28), 1.0),
)


def obstacles_near(rng: np.random.Generator, x: float, z: float) -> tuple[Obstacle, ...]:
    """One to three obstacles around (x, z): in front of, beside or behind the object,
    some close enough for the hand to dip into them."""
    out = []
    for _ in range(rng.integers(1, 4)):
        category = str(rng.choice(sorted(OBSTACLE_CATEGORIES)))
        half = tuple(float(h) for h in np.asarray(OBSTACLE_CATEGORIES[category].half_extents) * rng.uniform(0.5, 1.5, 3))
        centre = (float(np.clip(x + rng.normal(0, 1.2), -5.5, 5.5)), float(np.clip(z + rng.normal(0, 1.2), -0.5, 9.5)))
        out.append(Obstacle(category, centre, half, float(rng.uniform(-np.pi, np.pi))))
    return tuple(out)


def test_composited_equals_full_render_with_obstacles(small, full):
    rng = np.random.default_rng(17)
    for i, (name, size, side, pose, palm, joints) in enumerate(random_states(rng, 30)):  # 30: 3 at 224 px
        renderer = full if i % 10 == 0 else small
        renderer.set_scene(name, size, side, obstacles_near(rng, pose[0], pose[2]))
        fast = renderer.render(pose, palm, joints)
        reference = renderer.render_full(pose, palm, joints)
        diff = np.argwhere((fast != reference).any(axis=2))
        assert diff.size == 0, f"{name} {side} pose={pose} palm={palm}: {len(diff)} pixels differ, e.g. {diff[:3]}"


def test_depth_ties_with_an_obstacle_fall_back_to_a_full_render(small):
    """A box sunk into an obstacle with its top face in the obstacle's top plane ties in
    depth with the obstacle's plate there."""
    cat = OBJECTS["toy_cube"]
    hy = cat.scaled_dims(cat.nominal_size)[1]
    brick = Obstacle("brick", (0.2, 4.0), (0.55, 0.28, 0.28), 0.0)
    pose = np.array([0.0, brick.height - hy, 4.0, *IDENTITY])
    small.set_scene("toy_cube", cat.nominal_size, None, (brick,))
    before = small.fallbacks
    fast = small.render(pose)
    assert small.fallbacks == before + 1
    assert np.array_equal(fast, small.render_full(pose))


def test_obstacles_show_their_category_colour_and_turn_as_ry(full):
    full.set_scene(None, None, None)
    plate = full.render()
    for category, kind in sorted(OBSTACLE_CATEGORIES.items()):
        box = Obstacle(category, (0.5, 4.0), kind.half_extents, 0.4)
        full.set_scene(None, None, None, (box,))
        img = full.render()
        row, col = pixel_of((0.5, box.height, 4.0), FULL)
        assert matches(img[row, col], kind.rgba), (category, img[row, col])
        assert fraction(img[row - 2 : row + 3, col - 2 : col + 3], kind.rgba) >= 0.8, category
        assert (img != plate).any(axis=2).sum() >= 100
    book = OBSTACLE_CATEGORIES["book"]
    long = Obstacle("book", (0.0, 4.5), (1.2, 0.15, 0.2), np.pi / 2)  # +X turned onto -Z
    full.set_scene(None, None, None, (long,))
    img = full.render()
    for dz in (-1.0, 1.0):
        assert matches(img[pixel_of((0.0, 0.3, 4.5 + dz), FULL)], book.rgba)
    for dx in (-0.6, 0.6):
        assert not matches(img[pixel_of((dx, 0.3, 4.5), FULL)], book.rgba)
    full.set_scene(None, None, None)
    assert np.array_equal(full.render(), plate), "a scene without obstacles draws the renderer's own plate"


def test_scenes_without_obstacles_are_unchanged_by_earlier_obstacle_scenes(small):
    rng = np.random.default_rng(5)
    states = list(random_states(rng, 4))
    with Renderer(SMALL, kind="full") as fresh:
        expected = []
        for name, size, side, pose, palm, joints in states:
            fresh.set_scene(name, size, side)
            expected.append(fresh.render(pose, palm, joints))
    for (name, size, side, pose, palm, joints), image in zip(states, expected):
        small.set_scene(name, size, side, OBSTACLES)
        small.render(pose, palm, joints)
        small.render_full(pose, palm, joints)
        small.set_scene(name, size, side)
        assert np.array_equal(small.render(pose, palm, joints), image)
        assert np.array_equal(small.render_full(pose, palm, joints), image)


def test_render_episode_draws_each_frame(small):
    n = 4
    size, pose = resting("sugar_box", -1.0, 3.0)
    poses = np.repeat(pose[None], n, axis=0).astype(np.float32)
    poses[:, 0] += np.arange(n) * 0.5
    palms = np.repeat(np.asarray(REST_PALM, dtype=np.float32)[None], n, axis=0)
    palms[:, 1] -= np.arange(n) * 0.5
    zeros = lambda w: np.zeros((n, w), dtype=np.float32)  # noqa: E731
    frames = EpisodeFrames(
        phase=np.zeros(n, dtype=np.int8),
        object_pose=poses,
        object_velocity=zeros(3),
        palm_pose=palms,
        joint_angles=zeros(15),
        joint_poses=zeros(90),
        keypoints=zeros(36),
        action=zeros(18),
        fingertip_distance=np.zeros(n, dtype=np.float32),
        palm_distance=np.zeros(n, dtype=np.float32),
        grasp_angles=np.zeros(15, dtype=np.float32),
    )
    images = small.render_episode(frames, "sugar_box", size, "right")
    assert len(images) == n
    assert all(not np.array_equal(images[0], im) for im in images[1:])
    for i, img in enumerate(images):
        assert np.array_equal(img, small.render_full(poses[i], palms[i], np.zeros(15)))
    assert [np.array_equal(a, b) for a, b in zip(images, small.render_episode(frames, "sugar_box", size, "right", full=True))] == [True] * n
    among = small.render_episode(frames, "sugar_box", size, "right", obstacles=OBSTACLES)
    assert all(not np.array_equal(a, b) for a, b in zip(images, among))
    assert [np.array_equal(a, b) for a, b in zip(among, small.render_episode(frames, "sugar_box", size, "right", True, OBSTACLES))] == [True] * n


def test_bad_arguments_are_rejected(small):
    with pytest.raises(SpecError, match="unknown object"):
        small.set_scene("anvil", 1.0, None)
    with pytest.raises(SpecError, match="hand"):
        small.set_scene(None, None, "middle")
    with pytest.raises(SpecError, match="object_size"):
        small.set_scene("orange", -1.0, None)
    small.set_scene("orange", 0.8, "right")
    with pytest.raises(SpecError, match="object_pose"):
        small.render(np.zeros(6), REST_PALM, REST_JOINTS)
    with pytest.raises(SpecError, match="palm_pose"):
        small.render(np.array([0, 0.4, 3, 0, 0, 0, 1.0]), REST_PALM, np.zeros(14))
    with pytest.raises(SpecError, match="resolution"):
        Renderer(4)
    with pytest.raises(SpecError, match=r"obstacles\[0\]"):
        small.set_scene("orange", 0.8, "right", [{"category": "crate"}])
    with pytest.raises(SpecError, match="obstacles"):
        small.set_scene("orange", 0.8, "right", OBSTACLES[0])


def test_wrongly_typed_arguments_are_spec_errors(small):
    with pytest.raises(SpecError, match="object_size"):
        small.set_scene("orange", "0.8", None)
    with pytest.raises(SpecError, match="object_size"):
        small.set_scene("orange", True, None)
    with pytest.raises(SpecError, match="object"):
        small.set_scene(["orange"], 0.8, None)
    with pytest.raises(SpecError, match="hand"):
        small.set_scene(None, None, ["right"])
    small.set_scene("orange", np.float32(0.8), "right")
    with pytest.raises(SpecError, match="object_pose"):
        small.render(["x"] * 7, REST_PALM, REST_JOINTS)
    with pytest.raises(SpecError, match="palm_pose"):
        small.render(np.array([0, 0.4, 3, 0, 0, 0, 1.0]), {"x": 1}, REST_JOINTS)
    for width in ("wide", 16.5, True):
        with pytest.raises(SpecError, match="width"):
            Renderer(16, width=width)


def test_jpeg_round_trip_quality_and_determinism(small):
    small.set_scene("baseball", 0.74, "right")
    img = small.render(np.array([0.0, 0.37, 3.0, *IDENTITY]), REST_PALM, REST_JOINTS)
    default = encode_jpeg(img)
    assert default == encode_jpeg(img, JPEG_QUALITY) == encode_jpeg(img.copy())
    assert default[:2] == b"\xff\xd8"
    errors, sizes = [], []
    for quality in (30, 60, 95):
        data = encode_jpeg(img, quality)
        back = decode_jpeg(data)
        assert back.shape == img.shape and back.dtype == np.uint8
        errors.append(np.abs(back.astype(int) - img).mean())
        sizes.append(len(data))
    assert sizes[0] < sizes[1] < sizes[2]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 2.0  # RGB order survives the round trip
    with pytest.raises(SpecError, match="quality"):
        encode_jpeg(img, 0)
    with pytest.raises(SpecError, match="uint8"):
        encode_jpeg(img.astype(np.float32))
    with pytest.raises(ShardError):
        decode_jpeg(b"not a jpeg at all")


def test_egl_renderer_draws_a_comparable_image(full):
    """Where pybullet's EGL plugin loads, it shows the same bodies in the same places
    (its shading differs: silhouettes are compared, not colours)."""
    try:
        egl = Renderer(FULL, backend="egl")
    except RendererUnavailable as exc:
        pytest.skip(f"EGL renderer unavailable: {exc}")
    with egl:
        masks = []
        size, pose = resting("cracker_box", 1.5, 4.0)
        palm = np.array([-1.0, 1.5, 3.0, 0.0, 0.0, 0.3])
        for renderer in (full, egl):
            renderer.set_scene(None, None, None)
            plate = renderer.render()
            renderer.set_scene("cracker_box", size, "right")
            img = renderer.render(pose, palm, REST_JOINTS)
            masks.append((img != plate).any(axis=2))
        tiny_mask, egl_mask = masks
        for point in (pose[:3], palm[:3]):
            row, col = pixel_of(point, FULL)
            assert tiny_mask[row, col] and egl_mask[row, col]
        near = lambda m: cv2.dilate(m.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)  # noqa: E731
        assert (tiny_mask & near(egl_mask)).sum() >= 0.9 * tiny_mask.sum()
        assert (egl_mask & near(tiny_mask)).sum() >= 0.9 * egl_mask.sum()  # GL adds a few highlight pixels


def test_a_frame_does_not_depend_on_what_the_renderer_drew_before():
    """Episode 116 of circular-medium, frame 60, holds an exact depth tie between two hand
    surfaces; TinyRenderer settles it by draw order, which a renderer's history used to
    perturb (1 and 2 build workers then disagreed on one pixel). Fresh and used renderers,
    composited and full renders must all agree."""
    from generators.recipe import spec_for
    from pipeline.stages.episode import episode

    def tie_frame(renderer: Renderer) -> tuple[np.ndarray, np.ndarray]:
        spec = spec_for("circular-medium", 116)
        frames = episode(spec)
        renderer.set_scene(spec.object, spec.object_size, spec.hand)
        state = frames.object_pose[60], frames.palm_pose[60], frames.joint_angles[60]
        return renderer.render(*state), renderer.render_full(*state)

    with Renderer(224, kind="full") as fresh:
        composited, full = tie_frame(fresh)
    with Renderer(224, kind="full") as used:
        for index in range(12):
            spec = spec_for("harmonic-fast", index)
            frames = episode(spec)
            used.set_scene(spec.object, spec.object_size, spec.hand)
            used.render(frames.object_pose[0], frames.palm_pose[0], frames.joint_angles[0])
            used.render_full(frames.object_pose[0], frames.palm_pose[0], frames.joint_angles[0])
        again, again_full = tie_frame(used)
    assert np.array_equal(composited, full)
    assert np.array_equal(again, composited)
    assert np.array_equal(again_full, full)


def test_a_scene_starts_from_fresh_bodies_whatever_was_drawn_before():
    """TinyRenderer normalises every stored vertex normal in place on each draw, so a
    body's first draw can shade a pixel a level differently from its later draws (here
    circular-slow episode 18143, frame 51, a toy cube under the opposed hand of 5.0.0; 4.x's
    splayed hand showed it at episode 17611, frame 73). A renderer that drew other episodes with the
    same hand before must still draw an episode's first frame with fresh bodies."""
    from generators.recipe import spec_for
    from pipeline.stages.episode import episode

    spec = spec_for("circular-slow", 18143)
    state = (lambda f: (f.object_pose[51], f.palm_pose[51], f.joint_angles[51]))(episode(spec))
    with Renderer(224, kind="full") as fresh:
        fresh.set_scene(spec.object, spec.object_size, spec.hand)
        first, second = fresh.render(*state), fresh.render(*state)
    assert not np.array_equal(first, second), "premise: a body's first and second draws differ here"
    with Renderer(224, kind="full") as used:
        for index in range(3):
            other = spec_for("harmonic-fast", index)
            frames = episode(other)
            used.set_scene(other.object, other.object_size, spec.hand)
            for k in range(3):
                used.render(frames.object_pose[k], frames.palm_pose[k], frames.joint_angles[k])
        used.set_scene(spec.object, spec.object_size, spec.hand)
        assert np.array_equal(used.render(*state), first)
        assert np.array_equal(used.render(*state), second)


def test_bgr_frames_and_their_jpeg_equal_the_rgb_ones(small):
    from generators.encode import encode_bgr_jpeg

    rng = np.random.default_rng(5)
    for name, size, side, pose, palm, joints in random_states(rng, 12):
        small.set_scene(name, size, side)
        rgb = small.render(pose, palm, joints)
        bgr = small.render_bgr(pose, palm, joints)
        assert bgr.flags.c_contiguous and np.array_equal(bgr, rgb[:, :, ::-1])
        assert encode_bgr_jpeg(bgr) == encode_jpeg(rgb) == encode_jpeg(np.ascontiguousarray(rgb[:, ::-1])[:, ::-1])
    small.set_scene(None, None, None)
    assert np.array_equal(small.render_bgr(), small.render()[:, :, ::-1])
    with pytest.raises(SpecError, match="uint8"):
        encode_bgr_jpeg(rgb[:, :, :2])


def test_tie_fallbacks_give_bgr_frames_too(small):
    cat = OBJECTS["toy_cube"]
    hy = cat.scaled_dims(cat.nominal_size)[1]
    pose = np.array([0.0, -TABLE_TOP_GAP - hy, 4.0, *IDENTITY])
    small.set_scene("toy_cube", cat.nominal_size, None)
    before = small.fallbacks
    assert np.array_equal(small.render_bgr(pose), small.render_full(pose)[:, :, ::-1])
    assert small.fallbacks == before + 1


def test_frames_do_not_depend_on_when_the_moving_client_was_last_reset(monkeypatch):
    """The moving client is emptied by removing its bodies and, every RESET_EVERY scenes,
    reset instead: either way a scene's frames equal a fresh renderer's."""
    import generators.render as render

    rng = np.random.default_rng(23)
    states = list(random_states(rng, 5))
    fresh = []
    for name, size, side, pose, palm, joints in states:
        with Renderer(SMALL, kind="full") as once:
            once.set_scene(name, size, side)
            fresh.append([once.render(pose, palm, joints), once.render(pose, palm, joints)])
    for every in (1, 2, 3):
        monkeypatch.setattr(render, "RESET_EVERY", every)
        with Renderer(SMALL, kind="full") as used:
            for (name, size, side, pose, palm, joints), expected in zip(states, fresh):
                used.set_scene(name, size, side)
                assert np.array_equal(used.render(pose, palm, joints), expected[0]), (every, name)
                assert np.array_equal(used.render(pose, palm, joints), expected[1]), (every, name)
