"""The limits of a spec and of a specs file, in one place, each with its reason.

Every value of an :class:`~schemas.spec.EpisodeSpec` and the specs file itself are
bounded, and checked when a spec is built or read, before anything is allocated: a
spec that passes is at most a minute of episode. The recipe draws far inside
every limit (its longest episode is 140 frames, its fastest target 3 units/s). Units:
1 unit = 10 cm, angles in radians, times in seconds, at :data:`schemas.versions.FPS`
(20) frames per second.

| Constant | Value | Bounds | Why |
| --- | --- | --- | --- |
| `MAX_NUM_FRAMES` | 1,200 frames (60 s) | `num_frames`, `observe_frames` | 8x the recipe's longest episode (140) |
| `MAX_SECONDS` | 120 s | a token's `duration`; an overlay's start, end | twice the longest episode |
| `MAX_POSITION` | 100 units (10 m) | each coordinate of `start`, `centre` | far past the table and the 40-unit view |
| `MIN_RADIUS`, `MAX_RADIUS` | 0.01, 100 units | `A.radius` | a 1 mm circle spins in place |
| `MAX_AMPLITUDE` | 100 units | `H.amplitude` | as `MAX_POSITION` |
| `MAX_SPEED` | 100 units/s (10 m/s) | speeds, `H.drift`, `P.velocity`, a token's peak speed | 5 units a frame at 20 FPS |
| `MAX_ACCELERATION` | 2,000 units/s^2 | `L.acceleration`, `P.gravity` | rest to `MAX_SPEED` in one frame |
| `MAX_TURN_RATE` | 20 pi rad/s | `A.angular_velocity` | half a turn a frame: faster turns alias |
| `MAX_FREQUENCY` | 10 Hz | `H.frequency` | a 20 FPS camera's Nyquist frequency |
| `MAX_CURVATURE` | 100 per unit | `C.curvature` | a radius of 1 mm, as `MIN_RADIUS` |
| `MAX_CURVATURE_SLOPE` | 10,000 per unit^2 | `C.curvature_slope` | 0 to `MAX_CURVATURE` in 1 cm of path |
| `MAX_TURNING` | 64 pi rad (32 turns) | a `C`'s heading change at its own speed | a connector turns a few times |
| `MAX_ANGLE` | 8 pi rad (4 turns) | every angle (`direction`, `phase`, `yaw`...) | beyond, only precision is lost |
| `MAX_HEIGHT` | 100 units | `P.height` | as `MAX_POSITION` |
| `MAX_TRACK_TOKENS` | 256 | tokens of one track | the recipe uses up to 6 |
| `MAX_OVERLAYS` | 16 | overlay tracks of a motion | the recipe uses none |
| `MAX_TEXT` | 10,000 characters | `text` | an instruction is a sentence |
| `MAX_NUMBER_DIGITS` | 40 | digits of any integer in the JSON | `seed` (int64) needs 19 |
| `MIN_RESOLUTION`, `MAX_RESOLUTION` | 8, 1,024 px | an image side, a task's `resolution` | 3 MB a frame, not gigabytes |
| `MAX_SPEC_LINE_BYTES` | 2 MiB | one line of a specs file | the largest spec these limits admit fits |
| `MAX_SPECS_FILE_BYTES` | 256 MiB | a specs file | Dyana-12M's 184,718 specs (~90 MB) fit |

A specs file must also be a regular file (not a device, FIFO or folder), and a JSON key
may appear only once in an object, at any depth.
"""

from __future__ import annotations

import math

MAX_NUM_FRAMES = 1_200
MAX_SECONDS = 120.0
MAX_POSITION = 100.0
MAX_RADIUS = 100.0
MIN_RADIUS = 0.01
MAX_AMPLITUDE = 100.0
MAX_SPEED = 100.0
MAX_ACCELERATION = 2_000.0
MAX_TURN_RATE = 20.0 * math.pi
MAX_FREQUENCY = 10.0
MAX_CURVATURE = 100.0
MAX_CURVATURE_SLOPE = 10_000.0
MAX_TURNING = 64.0 * math.pi
MAX_ANGLE = 8.0 * math.pi
MAX_HEIGHT = 100.0
MAX_TRACK_TOKENS = 256
MAX_OVERLAYS = 16
MAX_TEXT = 10_000
MAX_NUMBER_DIGITS = 40
MIN_RESOLUTION = 8
MAX_RESOLUTION = 1024
MAX_SPEC_LINE_BYTES = 2 * 1024 * 1024
MAX_SPECS_FILE_BYTES = 256 * 1024 * 1024
