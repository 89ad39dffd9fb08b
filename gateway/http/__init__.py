"""The gateway's HTTP child process: the API (:mod:`gateway.http.api`), its server (:mod:`gateway.http.server`), the
Prometheus metrics (:mod:`gateway.http.metrics`) and the operator page (``static/``).
"""

__all__ = [
    "api",
    "metrics",
    "server",
]
