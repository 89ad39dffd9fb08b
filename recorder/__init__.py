"""Recordings of the cell in MCAP, and their replay through the gateway.

- :mod:`recorder.mcap_sink`: an MCAP file written from a bounded queue by a background thread, JSON messages
  with JSON Schemas generated from the project's pydantic models;
- :mod:`recorder.scene`: ``foxglove.SceneUpdate`` capsules (Foxglove, Lichtblick 3D panel);
- :mod:`recorder.cell`: ``hrc-record``, every cell topic as a Zenoh member with the ``recorder`` certificate;
- :mod:`recorder.gateway_log`: what ``hrc-gateway --record`` writes (inputs, cycles, config) and reads back;
- :mod:`recorder.replay`: ``hrc-replay``, a gateway recording fed through a new gateway node on its own clock.
"""
