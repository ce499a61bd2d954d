"""Lightning's device banners (``GPU available: False, used: False``, ``TPU available: ...``)
and tips held back while a Trainer is built, so that they never stand before slimseg's own one-line
error: a run that fails on its data prints that line alone. What the banners say is logged
by slimseg once, at DEBUG."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager

log = logging.getLogger(__name__)

BANNER_LOGGERS = ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.rank_zero")
BANNER_PREFIXES = (
    "GPU available:",
    "TPU available:",
    "HPU available:",
    "IPU available:",
    "💡 Tip:",  # Lightning's advertisement of its add-ons (litlogger, ...)
)


class _HoldBanners(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if text.startswith(BANNER_PREFIXES):
            log.debug("lightning: %s", text)
            return False
        return True


@contextmanager
def quiet_device_banners() -> Iterator[None]:
    """For the block, Lightning's device-availability lines go to slimseg's DEBUG log instead
    of the console; the loggers are as they were afterwards."""
    hold = _HoldBanners()
    loggers = [logging.getLogger(name) for name in BANNER_LOGGERS]
    for lg in loggers:
        lg.addFilter(hold)
    try:
        yield
    finally:
        for lg in loggers:
            lg.removeFilter(hold)
