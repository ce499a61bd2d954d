"""Which topics of a bag are the colour, depth and ``camera_info`` streams.

A topic named on the command line must exist with a fitting type. Otherwise image topics
(``sensor_msgs/Image`` or ``CompressedImage``) whose name holds ``depth`` are depth candidates,
the others colour candidates; a ``camera_info`` topic in the colour topic's namespace (or the
only one) goes with it. Exactly one candidate is chosen and the choice is said
(:attr:`TopicChoice.why`); none or several end in one line listing what the bag holds and the
option to give.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from slimseg.data.bags.header import CAMERA_INFO, COMPRESSED, IMAGE
from slimseg.errors import SlimsegError

IMAGE_TYPES = (IMAGE, COMPRESSED)


@dataclass(frozen=True)
class TopicChoice:
    """The chosen topics (``info`` None: the bag has no ``camera_info``) and, per kind, how
    each was chosen (``{"colour": "given", "depth": "the only depth topic", ...}``)."""

    rgb: str
    depth: str
    info: str | None
    why: dict[str, str] = field(default_factory=dict)


Held = dict[str, str] | None
"""``{topic: the type as the recording names it}`` where that differs from its role (a Foxglove
``foxglove.RawImage (protobuf)`` topic plays ``sensor_msgs/msg/Image``): what listings show."""


def _listing(topics: dict[str, str], held: Held = None) -> str:
    names = {t: (held or {}).get(t, ty).rsplit("/", 1)[-1] for t, ty in topics.items()}
    return ", ".join(f"{t} ({names[t]})" for t in sorted(topics)) or "none"


def _given(
    bag: str, topics: dict[str, str], topic: str, types: tuple[str, ...], opt: str, held: Held
) -> str:
    if topic not in topics:
        raise SlimsegError(
            f"{opt} {topic}: bag {bag} has no such topic; it has {_listing(topics, held)}"
        )
    if topics[topic] not in types:
        shown = (held or {}).get(topic, topics[topic])
        raise SlimsegError(
            f"{opt} {topic}: in bag {bag} it carries {shown}, expected {' or '.join(types)}"
        )
    return topic


def _only(
    bag: str, kind: str, found: list[str], opt: str, topics: dict[str, str], held: Held
) -> str:
    if len(found) == 1:
        return found[0]
    if not found:
        raise SlimsegError(
            f"bag {bag} has no {kind} image topic (topics: {_listing(topics, held)}); name one "
            f"with {opt}"
        )
    raise SlimsegError(
        f"bag {bag} has {len(found)} candidate {kind} topics ({', '.join(sorted(found))}): "
        f"choose one with {opt}"
    )


def choose_colour(
    bag: str, topics: dict[str, str], rgb: str | None = None, held: Held = None
) -> tuple[str, str]:
    """The colour topic (``rgb``: the user's choice, checked) and how it was chosen."""
    if rgb is not None:
        return _given(bag, topics, rgb, IMAGE_TYPES, "--rgb-topic", held), "--rgb-topic"
    images = [t for t, ty in topics.items() if ty in IMAGE_TYPES and "depth" not in t.lower()]
    chosen = _only(bag, "colour", images, "--rgb-topic", topics, held)
    return chosen, "the only colour image topic"


def choose_topics(
    bag: str,
    topics: dict[str, str],
    rgb: str | None = None,
    depth: str | None = None,
    info: str | None = None,
    held: Held = None,
) -> TopicChoice:
    """Pick the colour, depth and ``camera_info`` topics of a bag holding ``topics``
    (``{topic: message type}``, the ROS 2 name of its role); ``rgb`` / ``depth`` / ``info``:
    the user's choice, if any; ``held``: the types as the recording names them, for listings."""
    why: dict[str, str] = {}
    images = [t for t, ty in topics.items() if ty in IMAGE_TYPES]
    rgb, why["colour"] = choose_colour(bag, topics, rgb, held)
    if depth is None:
        depth = _only(bag, "depth", [t for t in images if "depth" in t.lower() and t != rgb],
                      "--depth-topic", topics, held)  # fmt: skip
        why["depth"] = "the only depth image topic"
    else:
        depth = _given(bag, topics, depth, IMAGE_TYPES, "--depth-topic", held)
        why["depth"] = "--depth-topic"
    if depth == rgb:
        raise SlimsegError(f"bag {bag}: {rgb} is given as both the colour and the depth topic")
    if info is not None:
        why["camera_info"] = "--camera-info-topic"
        return TopicChoice(rgb, depth, _given(bag, topics, info, (CAMERA_INFO,),
                                              "--camera-info-topic", held), why)  # fmt: skip
    infos = sorted(t for t, ty in topics.items() if ty == CAMERA_INFO)
    space = rgb.rsplit("/", 1)[0] + "/"
    beside = [t for t in infos if t.startswith(space)]
    if len(infos) == 1:
        why["camera_info"] = "the only camera_info topic"
        return TopicChoice(rgb, depth, infos[0], why)
    if len(beside) == 1:
        why["camera_info"] = f"the camera_info topic beside {rgb}"
        return TopicChoice(rgb, depth, beside[0], why)
    if infos:
        raise SlimsegError(
            f"bag {bag} has {len(infos)} camera_info topics ({', '.join(infos)}) and none is "
            "the colour topic's alone: choose one with --camera-info-topic"
        )
    return TopicChoice(rgb, depth, None, why)
