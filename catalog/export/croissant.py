"""``croissant.json`` of a LeRobot export: Croissant 1.0 metadata (JSON-LD, mlcommons.org/croissant)
naming every file with its sha256 and describing the frames and the episodes as record sets,
so `mlcroissant` (and the dataset venues that read Croissant) can validate and load it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from catalog.export.layout import V30_EPISODES_PATH, VECTOR_NAMES, vector_names
from catalog.loader.lerobot_names import IMAGE_KEY, INDEX_FEATURES

CROISSANT = "croissant.json"
CROISSANT_CONFORMS_TO = "http://mlcommons.org/croissant/1.0"
#: The Croissant 1.0 JSON-LD context (as mlcroissant writes it).
CONTEXT: dict[str, Any] = {
    "@language": "en",
    "@vocab": "https://schema.org/",
    "citeAs": "cr:citeAs",
    "column": "cr:column",
    "conformsTo": "dct:conformsTo",
    "cr": "http://mlcommons.org/croissant/",
    "rai": "http://mlcommons.org/croissant/RAI/",
    "data": {"@id": "cr:data", "@type": "@json"},
    "dataType": {"@id": "cr:dataType", "@type": "@vocab"},
    "dct": "http://purl.org/dc/terms/",
    "examples": {"@id": "cr:examples", "@type": "@json"},
    "extract": "cr:extract",
    "field": "cr:field",
    "fileProperty": "cr:fileProperty",
    "fileObject": "cr:fileObject",
    "fileSet": "cr:fileSet",
    "format": "cr:format",
    "includes": "cr:includes",
    "isLiveDataset": "cr:isLiveDataset",
    "jsonPath": "cr:jsonPath",
    "key": "cr:key",
    "md5": "cr:md5",
    "parentField": "cr:parentField",
    "path": "cr:path",
    "recordSet": "cr:recordSet",
    "references": "cr:references",
    "regex": "cr:regex",
    "repeated": "cr:repeated",
    "replace": "cr:replace",
    "sc": "https://schema.org/",
    "separator": "cr:separator",
    "source": "cr:source",
    "subField": "cr:subField",
    "transform": "cr:transform",
}
ENCODINGS = {".parquet": "application/x-parquet", ".mp4": "video/mp4", ".json": "application/json",
             ".jsonl": "application/jsonlines", ".md": "text/markdown"}
DATA_FILES = "data/*/*.parquet"
#: The episodes' record set: LeRobot's columns and Dyana's provenance (name -> Croissant type).
EPISODE_FIELDS = {
    "episode_index": "sc:Integer", "length": "sc:Integer", "dyana/episode_id": "sc:Text", "dyana/slice": "sc:Text",
    "dyana/motion_type": "sc:Text", "dyana/intercept_setting": "sc:Text", "dyana/object": "sc:Text",
    "dyana/seed": "sc:Integer", "dyana/source_hash": "sc:Text", "dyana/source_episode_index": "sc:Integer",
}


def _encoding(path: str) -> str:
    return next((kind for suffix, kind in ENCODINGS.items() if path.endswith(suffix)), "application/octet-stream")


def _field(record_set: str, name: str, data_type: str, source: dict[str, Any], description: str,
           repeated: bool = False) -> dict[str, Any]:
    field: dict[str, Any] = {"@type": "cr:Field", "@id": f"{record_set}/{name}", "name": name,
                             "description": description, "dataType": data_type, "source": source}
    if repeated:
        field["repeated"] = True
    return field


def _frames(environment_state: bool) -> dict[str, Any]:
    fields = []
    for key, names in vector_names(environment_state).items():
        fields.append(_field("frames", key, "sc:Float", {"fileSet": {"@id": "data-files"}, "extract": {"column": key}},
                             f"float32[{len(names)}]: " + ", ".join(VECTOR_NAMES[key]), repeated=True))
    for key in INDEX_FEATURES:
        fields.append(_field("frames", key, "sc:Float" if key == "timestamp" else "sc:Integer",
                             {"fileSet": {"@id": "data-files"}, "extract": {"column": key}},
                             "frame_index / fps, seconds" if key == "timestamp" else f"LeRobot's {key}"))
    return {"@type": "cr:RecordSet", "@id": "frames", "name": "frames",
            "description": f"One record a frame (20 per second); the images are the videos of {IMAGE_KEY}",
            "field": fields}


def _episodes(version: str) -> dict[str, Any]:
    source = ({"fileSet": {"@id": "episodes-files"}} if version == "v3.0"
              else {"fileObject": {"@id": "meta/episodes.jsonl"}})
    fields = [_field("episodes", name, kind, {**source, "extract": {"column": name}}, f"the episode's {name}")
              for name, kind in EPISODE_FIELDS.items()]
    return {"@type": "cr:RecordSet", "@id": "episodes", "name": "episodes",
            "description": "One record an episode: its length and where it came from (meta/ holds every fact)",
            "field": fields}


def croissant(title: str, description: str, license_url: str, cite_as: str, dataset_version: str,
              lerobot_version: str, files: Mapping[str, Mapping[str, Any]], environment_state: bool,
              keywords: Sequence[str]) -> dict[str, Any]:
    """The Croissant document: every file in ``files`` (path -> sha256 and size) as a
    FileObject, the data files as a FileSet, and the frames and episodes record sets."""
    distribution: list[dict[str, Any]] = [
        {"@type": "cr:FileObject", "@id": path, "name": path, "contentUrl": path, "encodingFormat": _encoding(path),
         "contentSize": f"{record['size']} B", "sha256": record["sha256"]}
        for path, record in sorted(files.items())
    ]
    distribution.append({"@type": "cr:FileSet", "@id": "data-files", "name": "data-files",
                         "description": "The frames' Parquet files", "encodingFormat": ENCODINGS[".parquet"],
                         "includes": DATA_FILES})
    if lerobot_version == "v3.0":
        distribution.append({"@type": "cr:FileSet", "@id": "episodes-files", "name": "episodes-files",
                             "description": "The episodes table", "encodingFormat": ENCODINGS[".parquet"],
                             "includes": V30_EPISODES_PATH.replace("chunk-000/file-000", "*/*")})
    return {
        "@context": CONTEXT,
        "@type": "sc:Dataset",
        "name": title,
        "description": description,
        "conformsTo": CROISSANT_CONFORMS_TO,
        "citeAs": cite_as,
        "license": license_url,
        "version": dataset_version,
        "keywords": list(keywords),
        "isAccessibleForFree": True,
        "distribution": distribution,
        "recordSet": [_frames(environment_state), _episodes(lerobot_version)],
    }
