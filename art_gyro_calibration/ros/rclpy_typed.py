"""Typed faces of the few rclpy calls the node makes whose Jazzy wheels carry no annotations.

rclpy ships ``py.typed`` but leaves some functions unannotated (``Node.get_logger``, the
``QoSProfile`` constructor): called from typed code they are errors under ``mypy --strict``.
Each is called here once, with the type it has.
"""

from __future__ import annotations

from typing import Any, Protocol, cast

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy


class Logger(Protocol):
    """rclpy's node logger (``RcutilsLogger``) as the node uses it; each call says whether it logged."""

    def info(self, message: str, **kwargs: Any) -> bool:
        """Log at INFO; ``kwargs`` as rclpy's (``throttle_duration_sec``, ``once``, ...)."""

    def warning(self, message: str, **kwargs: Any) -> bool:
        """Log at WARN."""

    def error(self, message: str, **kwargs: Any) -> bool:
        """Log at ERROR."""


def logger(node: Node) -> Logger:
    """The logger of ``node`` (its ``get_logger``), typed."""
    return cast(Logger, node.get_logger())   # type: ignore[no-untyped-call]  # rclpy: get_logger unannotated


def qos_profile(depth: int, **policies: DurabilityPolicy | ReliabilityPolicy) -> QoSProfile:
    """``QoSProfile(depth=depth, **policies)``, typed (``durability=``, ``reliability=``)."""
    return QoSProfile(depth=depth, **policies)   # type: ignore[no-untyped-call]  # rclpy: __init__ unannotated
