"""A bag's colour topic alone as a stream of frames (``slimseg predict --source BAG``): no
depth, no pairing. One pass over the headers gives the count and the rate; the frames are then
decoded one at a time in log-time order (constant memory)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from slimseg.data.bags.header import COMPRESSED
from slimseg.data.bags.image_messages import colour_from_compressed, colour_from_image
from slimseg.data.bags.reader import BagFile
from slimseg.data.bags.topics import choose_colour
from slimseg.errors import SlimsegError

DEFAULT_FPS = 30.0  # one frame: no interval to measure


class BagColour:
    """The colour frames of ``path`` (``rgb_topic``: None for the only colour topic).
    ``stamps``: header stamps (s), strictly increasing, else a one-line ``SlimsegError``."""

    def __init__(self, path: str | Path, rgb_topic: str | None = None) -> None:
        self.path = Path(path)
        self._bag = BagFile(self.path)
        try:
            self._index(rgb_topic)
        except BaseException:  # a refused recording is closed before the error goes up
            self._bag.close()
            raise

    def _index(self, rgb_topic: str | None) -> None:
        """The colour topic and its header stamps (one pass over the headers)."""
        self.topic, self.why = choose_colour(
            str(self.path), self._bag.topics, rgb_topic, self._bag.held
        )
        self._type = self._bag.topics[self.topic]
        self.stamps: list[float] = []
        for _, _, raw in self._bag.messages([self.topic]):
            t = self._bag.header(raw, self.topic).seconds
            if self.stamps and t <= self.stamps[-1]:
                raise SlimsegError(
                    f"bag {self.path}: header stamps on {self.topic} go backwards or repeat at "
                    f"message {len(self.stamps) + 1} ({self.stamps[-1]:.9f} then {t:.9f} s)"
                )
            self.stamps.append(t)
        if not self.stamps:
            raise SlimsegError(f"bag {self.path}: colour topic {self.topic} has no messages")

    @property
    def fps(self) -> float:
        """Frame rate from the median interval of the stamps."""
        s = np.asarray(self.stamps)
        return float(1.0 / np.median(np.diff(s))) if len(s) > 1 else DEFAULT_FPS

    def frames(self, only: set[int] | None = None) -> Iterator[tuple[str, str, np.ndarray]]:
        """``(stem, source, rgb uint8 [H, W, 3])`` per message (``only``: just those message
        indices, the others not decoded), stem the stamp with 6 decimals (the name
        ``slimseg dynamic`` and ``bag2tum`` give that frame)."""
        try:
            source = f"{self.path}:{self.topic}"
            msgs = self._bag.messages([self.topic])
            for i, (t, (_, _, raw)) in enumerate(zip(self.stamps, msgs, strict=True)):
                if only is not None and i not in only:
                    continue
                msg = self._bag.decode(raw, self._type, self.topic)
                try:
                    rgb = (
                        colour_from_compressed(msg)
                        if self._type == COMPRESSED
                        else colour_from_image(msg)
                    )
                except ValueError as e:
                    raise SlimsegError(f"bag {self.path}: {self.topic} at {t:.6f} s: {e}") from None
                yield f"{t:.6f}", source, rgb
        finally:  # exhausted, closed, or left by an error: the file is released
            self._bag.close()
