"""Bench ingest: reading devices into records, once, for every consumer.

* :mod:`bench.ingest.stamp` -- the stamp rule: each decoded record's own time.
* :mod:`bench.ingest.reader` -- one selector loop reading every device in chunks,
  reconnecting, and notifying listeners (python-can's Notifier/Listener model).
* :mod:`bench.ingest.pacer` -- the replay pacer of ``replay`` and ``dash SESSION``.
"""
