"""Service ``imu/static_bias`` (std_srvs/Trigger): a static bias collection, its deferred replies, its lifecycle.

A call starts a collection over ``bias_samples`` frames, or joins the one running and gets its
result; the reply comes when it ends. At most :data:`MAX_WAITING_CALLS` calls wait for one collection:
a call beyond is refused at once, with a reply that says so. Motion refuses it and keeps the previous bias (if there
is one: else the rate stays uncorrected); publishing goes on meanwhile with the previous bias.
``on_bias`` hears of every bias put in force (the node's ``imu/is_calibrated``, its covariance).
A collection the node's stop cuts short is not a refusal: it ends without a word, and only the
calls waiting for it are told why. The reply is deferred, not waited for:
the callback returns at once and the executor thread is free. A collection that gets no
frame for :data:`COLLECTION_STALL_S`, or that the shutdown cuts short, ends with the reason. Frames
come to a collection only while the signals from outside the gyro the calibration needs are current
(:class:`~art_gyro_calibration.compensation.FrameCorrector`): it waits for them, and a call says why it stalled.

With a parked bias (:meth:`StaticBiasService.enable_parked`) a timer also starts a collection whenever the robot is
parked, and aborts it when the robot moves; it ends as a call's does (a call meanwhile joins it), its refusals
counted by :class:`~art_gyro_calibration.parked.ParkedBias`, not told as the service's.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any, NamedTuple

from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile
from std_srvs.srv import Trigger  # type: ignore[import-untyped]  # ROS messages: untyped

from art_gyro_calibration.compensation import FrameCorrector
from art_gyro_calibration.parked import ParkedBias, check_parked
from art_gyro_calibration.ros.parameters import Settings
from art_gyro_calibration.static_bias import MotionError, StaticBias, StaticBiasCollector

# A static bias collection with no frame for this long has lost its gyro: it is abandoned.
COLLECTION_STALL_S = 5.0
# How often the parked bias looks whether to start a collection or abort the running one (s).
PARKED_CHECK_PERIOD_S = 0.1
# Calls to imu/static_bias that can wait for one collection at once: a call beyond is refused at once, with a reply.
MAX_WAITING_CALLS = 256


class _Collection(StaticBiasCollector):
    """One static bias collection, which the reader thread feeds and callers wait for."""

    __slots__ = ('bias', 'error', 'kept', 'last_sample', 'waiting')

    def __init__(self, samples: int, max_mean_dps: float, max_std_dps: float, keep_window: bool) -> None:
        super().__init__(samples, max_mean_dps, max_std_dps, keep_window)
        self.bias: StaticBias | None = None
        self.error = ''
        self.kept = ''   # what a refusal left in force, for the reply
        self.last_sample = time.monotonic()
        self.waiting: list[Any] = []   # request headers of the calls to answer when it ends

    def add(self, rate_dps: float, error_dps: float, t: float = 0.0, temp_c: float = 0.0,
            causal_dps: float = 0.0) -> bool:
        """Add a sample, noting when (a collection that gets none for long is abandoned)."""
        self.last_sample = time.monotonic()
        return super().add(rate_dps, error_dps, t, temp_c, causal_dps)


class _ParkedCollection(_Collection):
    """A collection the robot's being parked started: refused if its mean, with the bias in force, shows a turn."""

    __slots__ = ('reference', 'relative_max_mean_dps', 'gyro_stillness')

    def __init__(self, samples: int, max_mean_dps: float, max_std_dps: float, keep_window: bool,
                 reference: StaticBias, gyro_stillness: bool) -> None:
        # The service's mean check is on the mean itself; this one's is relative to the bias in force (result).
        super().__init__(samples, math.inf, max_std_dps, keep_window)
        self.reference = reference
        self.relative_max_mean_dps = max_mean_dps   # not max_mean_dps: the service's check, off here
        self.gyro_stillness = gyro_stillness

    def result(self) -> StaticBias:
        """The bias, refused (:class:`~art_gyro_calibration.parked.ParkedRefusal`) if it shows a turn."""
        bias = super().result()
        check_parked(bias, self.reference, self.relative_max_mean_dps, self.gyro_stillness)
        return bias


class BiasState(NamedTuple):
    """One consistent look at the static bias, for its diagnostics status.

    ``state`` is 'collecting' while a collection runs (``collected`` frames so far), else how
    the last one ended: 'none' yet, 'ok' or 'refused' (``refusal`` says why).
    """

    state: str
    bias: StaticBias
    refusal: str
    bias_time: float   # time.monotonic() when ``bias`` was found
    collected: int


class ParkedState(NamedTuple):
    """One consistent look at the parked bias, for its diagnostics status (``age_s``: inf before the first)."""

    parked: bool
    collecting: bool
    updates: int
    age_s: float
    refused: dict[str, int]
    last_refusal: str


class StaticBiasService:
    """The service on ``node``: feeds collections to ``corrector`` and sets its bias from them."""

    def __init__(self, node: Node, settings: Settings, corrector: FrameCorrector, closing: threading.Event,
                 link_error: Callable[[], str], on_bias: Callable[[], None] = lambda: None,
                 signal_problems: Callable[[], str] = str) -> None:
        """The service on ``node``; the callbacks say why a collection stalls, and hear of each bias.

        ``link_error`` says why the gyro sends nothing, ``signal_problems`` which extra signals are not
        current ('' when all are): for a collection that stalls. ``on_bias`` is called (on the reader
        thread, before the frame that completed the collection is published) each time a bias is put in force.
        """
        self._node = node
        self._logger = node.get_logger()   # type: ignore[no-untyped-call]  # rclpy leaves it unannotated
        self.signal_problems = signal_problems
        self._on_bias = on_bias
        self._settings = settings
        self._corrector = corrector
        self._closing = closing
        self._link_error = link_error
        self._lock = threading.Lock()
        self._collection: _Collection | None = None
        self._finished: list[_Collection] = []   # ended, their replies not sent yet
        self._outcome = 'none'
        self._refusal = ''
        self._bias_time = 0.0
        self.parked: ParkedBias | None = None   # with parked_bias.enabled: when a parked collection runs
        # The reply is deferred: the callback returns at once and the executor sends the reply
        # through send_response, which this takes over to hold it until the collection ends.
        # (rclpy 7 re-runs a waiting coroutine callback in a busy loop, so an async callback is not used.)
        # Queues that keep all: a burst of requests reaches the callback (which answers each, joined or
        # refused), and the replies to every joined call, sent at once, all go out. Keeping the last N
        # dropped the rest unanswered (3000 calls at once: 1037 replies with N = 1000).
        queue = QoSProfile(history=HistoryPolicy.KEEP_ALL)   # type: ignore[no-untyped-call]  # unannotated
        self._service = node.create_service(Trigger, 'imu/static_bias', lambda request, response: response,
                                            qos_profile=queue)
        self._send_reply = self._service.send_response
        self._service.send_response = self._defer_reply   # type: ignore[method-assign]  # the deferral, above
        self._replies = node.create_guard_condition(self._send_replies)
        node.create_timer(0.5, self._watch)

    def start(self) -> _Collection:
        """The collection running, started now if none was (a call, or the node's startup static bias)."""
        with self._lock:
            if self._collection is None:
                self._collection = _Collection(
                    self._settings.bias_samples, self._settings.static_bias_max_mean_dps,
                    self._settings.static_bias_max_std_dps, self._corrector.compensator.refinable)
                self._corrector.collect(self._collection, self._collected)
                self._logger.info(f'static bias: collecting {self._settings.bias_samples} samples; '
                                  'keep the gyro still')
            return self._collection

    def enable_parked(self, parked: ParkedBias) -> None:
        """Take a bias whenever ``parked`` says the robot is parked (its topic's words come to :meth:`put_parked`)."""
        self.parked = parked
        self._node.create_timer(PARKED_CHECK_PERIOD_S, self._check_parked)

    def put_parked(self, parked: bool) -> None:
        """The parked topic's word (executor thread)."""
        assert self.parked is not None
        with self._lock:
            self.parked.put(parked, time.monotonic())

    def _check_parked(self) -> None:
        """Start a parked collection when due; abort the running one when the robot moved or its topic fell silent."""
        parked = self.parked
        assert parked is not None
        if self._closing.is_set():
            return
        settings = self._settings
        with self._lock:
            now = time.monotonic()
            collection = self._collection
            if collection is None and parked.due(now):
                parked.start(now)
                max_std = settings.static_bias_max_std_dps
                if settings.parked_bias_gyro_stillness:
                    max_std = min(max_std, settings.parked_bias_max_std_dps)
                self._collection = _ParkedCollection(
                    settings.bias_samples, settings.static_bias_max_mean_dps, max_std,
                    self._corrector.compensator.refinable, self._corrector.compensator.bias,
                    settings.parked_bias_gyro_stillness)
                self._corrector.collect(self._collection, self._collected)
                self._logger.info(f'parked bias: collecting {settings.bias_samples} samples')
                return
            broken = parked.broken(now) if isinstance(collection, _ParkedCollection) else None
        if broken is not None:
            assert collection is not None
            self._end(collection, None, str(broken), broken)

    def _collected(self, collection: StaticBiasCollector) -> None:
        """The frame that completed ``collection`` (reader thread): its bias is used from that frame on.

        The one place a bias is put in force (:meth:`_end`, on the reader thread, inside the frame's step).
        """
        assert isinstance(collection, _Collection)
        parked = self.parked
        try:
            if parked is not None and isinstance(collection, _ParkedCollection):
                with self._lock:
                    broken = parked.broken(time.monotonic())
                if broken is not None:   # the robot moved since the timer last looked
                    raise broken
            bias = collection.result()
        except (MotionError, ValueError) as e:
            self._end(collection, None, str(e), e)
        else:
            self._end(collection, bias, '')

    def _end(self, collection: _Collection, bias: StaticBias | None, error: str, exception: Exception | None = None,
             stopping: bool = False) -> None:
        """End ``collection`` with ``bias`` or refused for ``error``; ``stopping``: cut short by the node's stop.

        A parked collection's refusal (``exception``, counted by the parked bias logic) is no service refusal:
        it is logged, and the static bias state stays as it was.

        The hand-off (:meth:`FrameCorrector.end_collection`) runs under the service's lock, with what
        :meth:`state` reads. A bias comes only from the reader thread; the timer and the stop end a
        collection without one, and a collection they ended that a last frame completes is ignored here.
        """
        with self._lock:
            if self._collection is not collection:
                return   # abandoned meanwhile
            self._collection = None
            self._corrector.end_collection(bias)
            parked = isinstance(collection, _ParkedCollection)
            if self.parked is not None:
                if parked and not stopping:
                    self.parked.ended(time.monotonic(), exception if bias is None else None)
                elif bias is not None:
                    self.parked.bias_taken(time.monotonic())
            if bias is not None:
                self._outcome = 'ok'
                self._bias_time = time.monotonic()
                self._logger.info(f'{"parked" if parked else "static"} bias: {bias.describe()}')
            elif parked and not stopping:
                self._logger.info(f'parked bias refused, {self._kept()}: {error}')
            elif not stopping:   # a stop is not a refusal: the state stays as it was, nothing is logged
                self._outcome = 'refused'
                self._refusal = error
                self._logger.warning(f'static bias refused, {self._kept()}: {error}')
            collection.bias = bias
            collection.error = error
            collection.kept = self._kept()
            self._finished.append(collection)
        if bias is not None:
            self._on_bias()
        if not stopping:
            # The replies go out on the executor (at a stop, the stopping caller sends them).
            self._replies.trigger()   # type: ignore[no-untyped-call]  # rclpy leaves it unannotated

    def _kept(self) -> str:
        """What a refusal leaves in force."""
        if self._corrector.compensator.bias.samples:
            return 'previous bias kept'
        return 'no static bias in force: the rate is published uncorrected (imu/is_calibrated false)'

    def _defer_reply(self, response: Trigger.Response, header: Any) -> None:
        """Take the place of the service's send_response: join (or start) the collection; reply when it ends."""
        if self._closing.is_set():
            response.success, response.message = False, 'refused: the node is shutting down'
            self._send_reply(response, header)
            return
        collection = self.start()
        with self._lock:
            if self._collection is collection:
                if len(collection.waiting) >= MAX_WAITING_CALLS:
                    response.success, response.message = False, (
                        f'refused: {MAX_WAITING_CALLS} calls already wait for the running collection (the most '
                        'the node keeps); call again when it ends')
                else:
                    collection.waiting.append(header)
                    return
            else:
                response = self._reply(collection)   # it ended meanwhile
        self._send_reply(response, header)

    @staticmethod
    def _reply(collection: _Collection) -> Trigger.Response:
        if collection.bias is not None:
            return Trigger.Response(success=True, message=collection.bias.describe())
        return Trigger.Response(success=False, message=f'refused, {collection.kept}: {collection.error}')

    def _send_replies(self) -> None:
        with self._lock:
            finished, self._finished = self._finished, []
        for collection in finished:
            response = self._reply(collection)
            for header in collection.waiting:
                self._send_reply(response, header)

    def _watch(self) -> None:
        """Give up a collection that gets no frames (the replies say why), or one the shutdown cuts short."""
        collection = self._collection
        if collection is None:
            return
        if self._closing.is_set():
            self._end(collection, None, 'the node is shutting down', stopping=True)
            self._send_replies()
        elif collection.waiting and time.monotonic() - collection.last_sample > COLLECTION_STALL_S:
            waiting = self.signal_problems()
            self._end(collection, None,
                      f'no frame to take for {COLLECTION_STALL_S:.0f} s: {waiting}' if waiting else
                      f'no frame from the gyro for {COLLECTION_STALL_S:.0f} s '
                      f'(link: {self._link_error() or "no data"})')

    def state(self) -> BiasState:
        """The static bias in use and where its collection stands, read together."""
        with self._lock:   # one consistent snapshot: the reader thread may end a collection meanwhile
            collection = self._collection
            return BiasState('collecting' if collection is not None else self._outcome,
                             self._corrector.compensator.bias, self._refusal, self._bias_time,
                             collection.count if collection is not None else 0)

    def parked_state(self) -> ParkedState | None:
        """Where the parked bias stands (None: not enabled)."""
        with self._lock:
            parked = self.parked
            if parked is None:
                return None
            now = time.monotonic()
            return ParkedState(parked.parked(now), isinstance(self._collection, _ParkedCollection), parked.updates,
                               now - parked.last_update, dict(parked.refused), parked.last_refusal)

    def close(self) -> None:
        """End a running collection (the driver is stopped): the calls waiting for it hear why, rather than time out."""
        collection = self._collection
        if collection is not None:
            self._end(collection, None, 'the node is shutting down', stopping=True)
            if not collection.waiting:
                return   # the start-up bias, say: nobody to tell
            try:
                self._send_replies()
            except Exception as e:   # the context may be shut down already (SIGINT): nothing more to say
                self._logger.warning(
                    f'static bias replies not sent at shutdown: {type(e).__name__}: {e}')
