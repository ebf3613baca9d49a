"""The fleet health page: a read-only HTTP view of the health store (``servowatch web``).

``view`` shapes the store's rows into the page's JSON, ``server`` serves the page and that
JSON on loopback, ``static/`` holds the page itself (HTML, CSS, JS; no external asset).
Part of ``service.edge``: may import what the edge may.
"""
