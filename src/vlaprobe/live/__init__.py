"""The live monitor (`vlaprobe serve`): episodes streamed step by step over a WebSocket, recorded, replayed.

``protocol`` (the messages, pydantic) · ``pipeline`` (record -> step message: probes, flips, cognition) ·
``sources`` (the simulator through the one step loop, or a stored episode) · ``session`` (the episode
thread) · ``hub`` (fan-out to clients, slow ones included) · ``recorder`` (episodes on disk) · ``replay`` ·
``app`` (FastAPI: /ws, /api, the UI) · ``serve`` (the command). Protocol and formats: docs/live.md.
"""
