"""The station's edge: every HTTP and WebSocket endpoint (fleet page, metrics, Foxglove feed),
their guards, and the status and fleet views they share with the CLI. May import the layers
below it (models, compat, log, store, monitor, wire, prognostics, sim), never daemon, replay or cli.
"""
