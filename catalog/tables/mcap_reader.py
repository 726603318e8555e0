"""Reads a shard's MCAP file (:mod:`catalog.tables.mcap_layout`): its summary, messages and
metadata records, the episodes' clock (:func:`read_timeline`), and a structural check
(:func:`check_mcap`). A damaged file raises ShardError naming it."""

from __future__ import annotations

import bisect
import json
import os
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, BinaryIO

from mcap.reader import NonSeekingReader, make_reader
from mcap_protobuf.decoder import DecoderFactory

from catalog.store.storage import open_binary
from catalog.tables.mcap_layout import IMAGE_SCHEMA, SHARD_METADATA, frame_period_ns, is_episode_record
from schemas.errors import ShardError
from schemas.versions import FPS


@dataclass(frozen=True)
class McapSummary:
    """What the summary section says: header, per-topic (schema, count), metadata count."""

    library: str
    profile: str
    message_count: int
    topics: Mapping[str, tuple[str, int]]
    metadata_count: int

    def count(self, schema_name: str) -> int:
        """Messages of ``schema_name`` over all topics."""
        return sum(n for name, n in self.topics.values() if name == schema_name)


@dataclass(frozen=True)
class McapMessage:
    topic: str
    schema: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    message: Any


def _fail(path: str | os.PathLike[str], exc: BaseException) -> ShardError:
    reason = f"{type(exc).__name__}: {exc}"
    return ShardError(f"{path}: not a readable MCAP file (truncated or corrupt): {reason}")


def _open(path: str | os.PathLike[str]) -> BinaryIO:
    try:
        return open_binary(path)
    except FileNotFoundError:
        raise ShardError(f"{path}: file is missing") from None
    except OSError as exc:
        raise ShardError(f"{path}: cannot open: {exc.strerror or exc}") from None


def mcap_summary(path: str | os.PathLike[str]) -> McapSummary:
    """Read the header and summary section (cheap: no chunk is decompressed)."""
    with _open(path) as stream:
        try:
            reader = make_reader(stream)
            header = reader.get_header()
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                raise ShardError(f"{os.fspath(path)}: MCAP file has no summary statistics")
            stats = summary.statistics
            topics = {}
            for channel_id, channel in sorted(summary.channels.items()):
                schema = summary.schemas.get(channel.schema_id)
                topics[channel.topic] = (schema.name if schema else "", stats.channel_message_counts.get(channel_id, 0))
        except ShardError:
            raise
        except Exception as exc:  # any parse failure of a damaged file
            raise _fail(path, exc) from None
    return McapSummary(header.library, header.profile, stats.message_count, topics, stats.metadata_count)


def iter_messages(
    path: str | os.PathLike[str], topics: Sequence[str] | None = None, decode: bool = True
) -> Iterator[McapMessage]:
    """Every message in file order, reading the whole file linearly and validating CRCs.

    With ``decode`` the protobuf payload is decoded, else ``message`` holds the raw bytes.
    A truncated or corrupt file raises ShardError naming it (after the intact messages).
    """
    wanted = None if topics is None else set(topics)
    decoders: dict[int, Any] = {}
    factory = DecoderFactory()
    with _open(path) as stream:
        try:
            reader = NonSeekingReader(stream, validate_crcs=True)
            for schema, channel, message in reader.iter_messages():
                if wanted is not None and channel.topic not in wanted:
                    continue
                payload: Any = message.data
                if decode:
                    if channel.schema_id not in decoders:
                        decoders[channel.schema_id] = factory.decoder_for(channel.message_encoding, schema)
                    decoder = decoders[channel.schema_id]
                    if decoder is None:
                        raise ShardError(f"{os.fspath(path)}: no protobuf decoder for topic {channel.topic!r}")
                    payload = decoder(message.data)
                yield McapMessage(
                    channel.topic,
                    schema.name if schema else "",
                    message.log_time,
                    message.publish_time,
                    message.sequence,
                    payload,
                )
        except ShardError:
            raise
        except Exception as exc:
            raise _fail(path, exc) from None


def count_messages(path: str | os.PathLike[str]) -> dict[tuple[str, str], int]:
    """(topic, schema) -> number of messages, counted by reading the whole file (CRCs checked)."""
    return dict(sorted(Counter((m.topic, m.schema) for m in iter_messages(path, decode=False)).items()))


def read_metadata(path: str | os.PathLike[str]) -> list[tuple[str, dict[str, str]]]:
    """Every metadata record as (name, key/values), in file order (through the summary's
    metadata index)."""
    with _open(path) as stream:
        try:
            return [(m.name, dict(m.metadata)) for m in make_reader(stream).iter_metadata()]
        except Exception as exc:
            raise _fail(path, exc) from None


def read_episode_metadata(path: str | os.PathLike[str]) -> list[dict[str, str]]:
    """Every episode's metadata record, in file order (named ``dyana.episode.NNNNNN``,
    or ``dyana.episode`` in files written before episodes had names of their own)."""
    return [data for name, data in read_metadata(path) if is_episode_record(name)]


@dataclass(frozen=True)
class EpisodeSpan:
    """Where one episode sits on its shard's clock."""

    episode_index: int
    start_ns: int
    frames: int | None


@dataclass(frozen=True)
class Timeline:
    """A shard's episodes on its clock, to map a log time back to (episode, frame)."""

    period_ns: int
    episodes: tuple[EpisodeSpan, ...]

    def locate(self, log_time_ns: int) -> tuple[int, int]:
        """``(episode_index, frame_index)`` of the frame logged at ``log_time_ns``."""
        starts = [e.start_ns for e in self.episodes]
        k = bisect.bisect_right(starts, log_time_ns) - 1
        if k >= 0:
            span = self.episodes[k]
            frame, rest = divmod(log_time_ns - span.start_ns, self.period_ns)
            if not rest and (span.frames is None or frame < span.frames):
                return span.episode_index, frame
        raise ShardError(f"log time {log_time_ns} ns is no frame of this shard's episodes")


def read_timeline(path: str | os.PathLike[str]) -> Timeline:
    """The shard's :class:`Timeline`, from its ``dyana.shard`` and episode metadata records."""
    records = read_metadata(path)
    shard = next((data for name, data in records if name == SHARD_METADATA), None)
    if shard is None:
        raise ShardError(f"{os.fspath(path)}: no {SHARD_METADATA} metadata record")
    try:
        period = frame_period_ns(int(json.loads(shard["settings"]).get("fps", FPS)))
        spans = tuple(
            EpisodeSpan(int(data["episode_index"]), int(data["start_time_ns"]),
                        int(data["frames"]) if "frames" in data else None)
            for name, data in records
            if is_episode_record(name)
        )
    except (KeyError, ValueError, AttributeError) as exc:
        raise ShardError(f"{os.fspath(path)}: malformed metadata record: {type(exc).__name__}: {exc}") from None
    if any(a.start_ns >= b.start_ns for a, b in zip(spans, spans[1:])):
        raise ShardError(f"{os.fspath(path)}: episode start times do not increase")
    return Timeline(period, spans)


def check_mcap(path: str | os.PathLike[str], frames: int | None = None, full: bool = False) -> McapSummary:
    """Structural check: the summary is readable, written by us, with one image per frame.

    ``full`` also reads every chunk and checks the CRCs and that the counted images
    agree with the summary.
    """
    summary = mcap_summary(path)
    if not summary.library.startswith("dyana/"):
        raise ShardError(f"{os.fspath(path)}: MCAP written by {summary.library!r}, not by dyana")
    images = summary.count(IMAGE_SCHEMA)
    if frames is not None and images != frames:
        raise ShardError(f"{os.fspath(path)}: {images} {IMAGE_SCHEMA} messages for {frames} frames")
    if full:
        counted = sum(n for (_, schema), n in count_messages(path).items() if schema == IMAGE_SCHEMA)
        if counted != images:
            raise ShardError(f"{os.fspath(path)}: {counted} {IMAGE_SCHEMA} messages read, summary says {images}")
    return summary
