"""Starting a dashboard's sources: the reader threads of a :class:`~bench.dash.app.DashConfig`.

Live devices are all read by one :class:`~bench.dash.sources.LiveSource` (the bench's one
ingest loop), each with a feed (and the scene's true poses for an ``arvaemu://`` receiver
when asked); a session directory is replayed by one
:class:`~bench.dash.sources.ReplaySource`. Readers talk to the app only through ``post``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from .sources import DeviceFeed, LiveSource, ReplaySource, SceneTruth


def start_sources(config, post: Callable) -> list:
    """Start the reader threads of ``config`` (a DashConfig); return the sources."""
    if config.replay is not None:
        # The links show where the bytes come from now: the session's raw logs.
        feeds = [DeviceFeed(replace(s, url=str(config.replay / f"{s.name}.raw")), post) for s in config.specs]
        sources = [ReplaySource(config.replay, feeds, config.replay_speed)]
    else:
        feeds = []
        for spec in config.specs:
            truth = SceneTruth.for_url(spec.url, spec.role) if config.scene_truth and spec.kind == "arva" else None
            feeds.append(DeviceFeed(spec, post, truth))
        sources = [LiveSource(feeds, config.stale_after)]  # one ingest loop reads them all
    for source in sources:
        source.start()
    return sources
