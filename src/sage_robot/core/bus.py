"""The bus: named, typed topics, services and actions between nodes (ROS 2 semantics).

- Topics: publish/subscribe. Each subscriber has a bounded queue that drops the
  *oldest* message when it falls behind (drops are counted); latched topics hand their
  last value to late subscribers (``/map``).
- Services: request/reply; a handler's exception comes back to the caller as
  :class:`ServiceError`; calls time out on the bus clock.
- Actions: :mod:`sage_robot.core.actions`.

The bus is in-process (asyncio). Where messages travel is a :class:`Transport`: the
default one keeps them local; a networked one (Zenoh) can forward publications to other
processes and deliver theirs without nodes changing.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import functools
import inspect
import logging
import threading
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar, overload

from sage_robot.core.clock import Clock, WallClock
from sage_robot.core.errors import ServiceError, ServiceTimeout, ServiceUnavailable

if TYPE_CHECKING:
    from sage_robot.core.actions import RemoteActions

M = TypeVar("M")
Req = TypeVar("Req")
Rep = TypeVar("Rep")

DEFAULT_QUEUE = 10  # messages kept per subscriber before the oldest is dropped
DEFAULT_SERVICE_TIMEOUT_S = 5.0

_log = logging.getLogger("sage.bus")


class Topic(str, Generic[M]):
    """A topic's name and the message type it carries, declared once
    (:mod:`sage_robot.core.topics`): ``Topic("/odom", Odometry)``.

    It is a ``str`` (equal to and hashing as its name), so it goes wherever a name goes: dict
    keys, a transport, a recording. To the bus it is typed: ``bus.publish(topics.ODOM,
    Twist())`` and ``bus.subscribe(topics.ODOM, Twist, ...)`` are type-check errors, and
    ``bus.latest(topics.MAP)`` is an ``OccupancyGrid | None``. A plain ``str`` name stays
    accepted, untyped. (mypy words a wrong message type as 'Cannot infer value of type
    parameter "M" of "publish"': the topic's type and the message's disagree.)
    """

    msg_type: type[M]
    latched: bool

    def __new__(cls, name: str, msg_type: type[M], latched: bool = False) -> Topic[M]:
        self = super().__new__(cls, name)
        self.msg_type = msg_type
        self.latched = latched  # in every process that uses it, publisher's or reader's
        return self

    # Pickling and copying rebuild it with its type. This return type also sets a Topic apart
    # from a plain str to the type checker (see PlainName): keep it.
    def __getnewargs__(self) -> tuple[str, type[M], bool]:  # type: ignore[override]
        return (str(self), self.msg_type, self.latched)


class PlainName(Protocol):
    """A topic name that is not a :class:`Topic`: any ``str`` matches, a Topic does not (its
    ``__getnewargs__`` differs). The bus's untyped overloads take this rather than ``str``,
    so that a Topic with the wrong message type is an error instead of falling through to
    the untyped overload (a Topic is a ``str``)."""

    def __getnewargs__(self) -> tuple[str]: ...


class Transport(ABC):
    """Carries publications beyond this process. The bus calls :meth:`send` for every local
    publication and hands :meth:`attach` a function that delivers remote ones locally (from
    any thread: the bus moves them onto its loop; a process's own publications must not come
    back to it). Only the topics the bus asked for with :meth:`want` (or all of them while
    :meth:`want_all` holds) need to come in."""

    @abstractmethod
    def attach(self, deliver: Callable[[str, Any], None]) -> None: ...

    @abstractmethod
    def send(self, topic: str, msg: Any) -> None: ...

    def want(self, topic: str, latched: bool) -> None:  # noqa: B027 - optional hook
        """A node here reads ``topic`` (asked once per topic): deliver other processes'
        publications on it from now on; for a latched topic, also the last one already made."""

    def unwant(self, topic: str) -> None:  # noqa: B027 - optional hook
        """Nobody here reads ``topic`` any more."""

    def want_all(self) -> Callable[[], None]:
        """Deliver every topic until the returned function is called (a recorder, a live
        view). Holds nest."""
        return lambda: None

    def matched(self, topic: str) -> bool:
        """Whether another process reads ``topic`` now; the default knows none."""
        return False

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release sockets; the default transport has none."""

    # Services beyond the process (optional): the bus offers each local service and asks the
    # transport for a service no local node offers.
    def offer(self, name: str, call: Callable[[Any], Awaitable[Any]]) -> None:  # noqa: B027
        """A local service that other processes may call (``call(request)`` → reply)."""

    def withdraw(self, name: str) -> None:  # noqa: B027
        """The local service is gone."""

    def has_service(self, name: str) -> bool:
        """Whether another process offers the service ``name``; the default knows none."""
        return False

    async def call(self, name: str, request: Any, timeout: float | None) -> Any:
        """Call a service of another process; the default knows none."""
        raise ServiceUnavailable(f"no node offers the service {name}")

    def remote_actions(self) -> RemoteActions | None:
        """Actions beyond the process (:mod:`sage_robot.core.actions`); the default has none."""
        return None


class LocalTransport(Transport):
    """Everything stays in this process."""

    def attach(self, deliver: Callable[[str, Any], None]) -> None:
        self._deliver = deliver

    def send(self, topic: str, msg: Any) -> None:
        return None


@dataclass
class TopicInfo:
    name: str
    msg_type: type
    latched: bool = False
    last: Any = None
    published: int = 0
    subscribers: list[Subscription[Any]] = field(default_factory=list)


class Subscription(Generic[M]):
    """A subscriber's bounded queue. Iterate it (``async for msg in sub``) or give a callback."""

    def __init__(self, bus: Bus, topic: TopicInfo, maxsize: int) -> None:
        if maxsize < 1:
            raise ValueError("subscriber queue size must be >= 1")
        self.bus, self.topic = bus, topic
        self._queue: deque[M] = deque(maxlen=maxsize)
        self._event = asyncio.Event()
        self.dropped = 0
        self.received = 0
        self.callback_errors = 0
        self.closed = False
        self._task: asyncio.Task[None] | None = None

    def _push(self, msg: M) -> None:
        if len(self._queue) == self._queue.maxlen:
            self.dropped += 1
        self._queue.append(msg)
        self.received += 1
        self._event.set()

    def pending(self) -> int:
        return len(self._queue)

    def get_nowait(self) -> M | None:
        return self._queue.popleft() if self._queue else None

    async def get(self) -> M:
        while not self._queue:
            if self.closed:
                raise StopAsyncIteration
            self._event.clear()
            await self._event.wait()
        return self._queue.popleft()

    def __aiter__(self) -> Subscription[M]:
        return self

    async def __anext__(self) -> M:
        return await self.get()

    def close(self) -> None:
        """Stop receiving; a callback task ends."""
        if self.closed:
            return
        self.closed = True
        if self in self.topic.subscribers:
            self.topic.subscribers.remove(self)
            self.bus._unwant(self.topic.name)
        self._event.set()
        if self._task is not None:
            self._task.cancel()

    def _start_callback(self, callback: Callable[[M], Any]) -> None:
        async def pump() -> None:
            while not self.closed:
                try:
                    msg = await self.get()
                except StopAsyncIteration:
                    return
                try:
                    result = callback(msg)
                    if inspect.isawaitable(result):
                        await result
                except asyncio.CancelledError:
                    raise
                except Exception:
                    self.callback_errors += 1
                    _log.exception("subscriber callback on %s failed", self.topic.name)

        self._task = asyncio.get_running_loop().create_task(pump(), name=f"sub:{self.topic.name}")


ServiceHandler = Callable[[Any], Awaitable[Any]]


@dataclass
class ServiceInfo:
    name: str
    handler: ServiceHandler
    calls: int = 0
    errors: int = 0


class Bus:
    """Topics and services between nodes, on one asyncio loop."""

    def __init__(self, clock: Clock | None = None, transport: Transport | None = None) -> None:
        self.clock = clock or WallClock()
        self.transport = transport or LocalTransport()
        self.remote_rejected = 0  # remote messages not delivered (wrong type, no loop yet)
        self._topics: dict[str, TopicInfo] = {}
        self._services: dict[str, ServiceInfo] = {}
        self._taps: list[Callable[[str, Any], None]] = []
        self._interest: dict[str, int] = {}  # topic -> readers here (asked of the transport while > 0)
        self._held: set[str] = set()  # topics read for good: latched declarations, latest(), want()
        self._inbox: deque[tuple[str, Any]] = deque()  # remote messages on their way to the loop
        self._inbox_lock = threading.Lock()
        self._drain_due = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: int | None = None
        self.transport.attach(self._deliver_remote)  # last: remote messages may come at once
        from sage_robot.core.actions import ActionRegistry  # the module builds on this one

        self.actions = ActionRegistry(self)

    # ------------------------------------------------------------ topics
    @overload
    def declare(
        self, name: Topic[M], msg_type: type[M] | None = None, latched: bool = False
    ) -> TopicInfo: ...
    @overload
    def declare(self, name: PlainName, msg_type: type, latched: bool = False) -> TopicInfo: ...
    def declare(self, name: Any, msg_type: type | None = None, latched: bool = False) -> TopicInfo:
        """Declare a topic's type (first use wins; a different type later is an error).
        A :class:`Topic` brings its own type and whether it is latched. Declaring a topic
        latched here means reading it: its last value comes from other processes too."""
        if isinstance(name, Topic):
            latched = latched or name.latched
        if msg_type is None:
            if not isinstance(name, Topic):
                raise TypeError(f"topic {name}: declare it with its message type")
            msg_type = name.msg_type
        elif isinstance(name, Topic) and name.msg_type is not msg_type:
            raise TypeError(f"topic {name} carries {name.msg_type.__name__}, not {msg_type.__name__}")
        info = self._topics.get(name)
        if info is None:
            info = self._topics[name] = TopicInfo(name, msg_type, latched)
        elif info.msg_type is not msg_type:
            raise TypeError(f"topic {name} carries {info.msg_type.__name__}, not {msg_type.__name__}")
        info.latched = info.latched or latched
        if latched:
            self._hold(name, True)
        return info

    def _info(self, name: str, msg: Any) -> TopicInfo:
        """The topic's record, declared on first use with its Topic's type (or the message's)."""
        info = self._topics.get(name)
        if info is None:
            info = self.declare(name, name.msg_type if isinstance(name, Topic) else type(msg))
        return info

    @overload
    def publish(self, name: Topic[M], msg: M) -> None: ...
    @overload
    def publish(self, name: PlainName, msg: Any) -> None: ...
    def publish(self, name: Any, msg: Any) -> None:
        """Publish on this loop's thread. Other threads use :meth:`publish_threadsafe`."""
        info = self._info(name, msg)
        if not isinstance(msg, info.msg_type):
            raise TypeError(f"topic {name} carries {info.msg_type.__name__}, got {type(msg).__name__}")
        self._bind_loop()
        self._deliver_local(name, msg)
        self.transport.send(name, msg)

    @overload
    def publish_threadsafe(self, name: Topic[M], msg: M) -> None: ...
    @overload
    def publish_threadsafe(self, name: PlainName, msg: Any) -> None: ...
    def publish_threadsafe(self, name: Any, msg: Any) -> None:
        """Publish from a driver thread (e.g. a serial RX thread)."""
        if self._loop is None or threading.get_ident() == self._loop_thread:
            self.publish(name, msg)
        elif not self._loop.is_closed():
            with contextlib.suppress(RuntimeError):  # the loop closed in between: shutting down
                # Carry the publishing thread's context (which node it belongs to) along.
                self._loop.call_soon_threadsafe(self.publish, name, msg, context=contextvars.copy_context())

    def _deliver_local(self, name: str, msg: Any) -> None:
        info = self._info(name, msg)
        info.published += 1
        if info.latched:
            info.last = msg
        for sub in list(info.subscribers):
            sub._push(msg)
        for tap in self._taps:
            tap(name, msg)

    def _deliver_remote(self, name: str, msg: Any) -> None:
        """A transport's delivery, from any thread: on the loop, checked against the topic's
        type, then as a local publication (never sent back out)."""
        loop = self._loop
        if loop is None or loop.is_closed():
            info = self._topics.get(name)
            if loop is None and info is not None and info.latched and isinstance(msg, info.msg_type):
                info.last = msg  # a latched value before anyone here subscribed: kept for them
                return
            self.remote_rejected += 1  # nobody here has subscribed or published yet
            return
        if threading.get_ident() != self._loop_thread:
            # One wake-up of the loop for a burst (odometry, battery and /clock of one tick).
            self._inbox.append((name, msg))
            with self._inbox_lock:
                if self._drain_due:
                    return
                self._drain_due = True
            with contextlib.suppress(RuntimeError):  # the loop closed in between: shutting down
                loop.call_soon_threadsafe(self._drain_inbox)
            return
        self._take_remote(name, msg)

    def _drain_inbox(self) -> None:
        with self._inbox_lock:
            self._drain_due = False
        while self._inbox:
            self._take_remote(*self._inbox.popleft())

    def _take_remote(self, name: str, msg: Any) -> None:
        info = self._topics.get(name)
        if info is not None and not isinstance(msg, info.msg_type):
            self.remote_rejected += 1
            _log.warning("remote %s on %s dropped: the topic carries %s", type(msg).__name__, name,
                         info.msg_type.__name__)
            return
        self._deliver_local(name, msg)

    def add_tap(self, tap: Callable[[str, Any], None]) -> Callable[[], None]:
        """See every publication on every topic (recorders, live views). Returns a remover.
        A tap runs inside ``publish``: it must be quick and must not raise. It sees other
        processes' publications only on topics wanted here (:meth:`want`, :meth:`want_all`)."""
        self._taps.append(tap)
        return lambda: self._taps.remove(tap) if tap in self._taps else None

    @overload
    def subscribe(
        self,
        name: Topic[M],
        msg_type: type[M],
        callback: Callable[[M], Any] | None = None,
        maxsize: int = DEFAULT_QUEUE,
    ) -> Subscription[M]: ...
    @overload
    def subscribe(
        self,
        name: PlainName,
        msg_type: type[M],
        callback: Callable[[M], Any] | None = None,
        maxsize: int = DEFAULT_QUEUE,
    ) -> Subscription[M]: ...
    def subscribe(
        self,
        name: Any,
        msg_type: type[M],
        callback: Callable[[M], Any] | None = None,
        maxsize: int = DEFAULT_QUEUE,
    ) -> Subscription[M]:
        """Subscribe to a topic. With a callback, a task calls it for each message."""
        info = self.declare(name, msg_type)
        self._bind_loop()
        sub: Subscription[M] = Subscription(self, info, maxsize)
        info.subscribers.append(sub)
        self._want(name, info.latched)  # until the subscription closes
        if info.latched and info.last is not None:
            sub._push(info.last)
        if callback is not None:
            sub._start_callback(callback)
        return sub

    @overload
    def latest(self, name: Topic[M]) -> M | None: ...
    @overload
    def latest(self, name: PlainName) -> Any: ...
    def latest(self, name: Any) -> Any:
        """The last value of a latched topic, or None. (In a process that did not declare the
        topic before, other processes' values come in from this first read on.)"""
        info = self._topics.get(name)
        self._hold(name, bool(info and info.latched))
        return info.last if info else None

    def want(self, name: str) -> None:
        """Have other processes' publications on ``name`` delivered here, for a tap (a
        subscription, a latched declaration or :meth:`latest` ask for theirs already)."""
        info = self._topics.get(name)
        self._hold(name, bool(info and info.latched) or bool(isinstance(name, Topic) and name.latched))

    def want_all(self) -> Callable[[], None]:
        """Have other processes' publications on every topic delivered here (a recorder or a
        live view of everything) until the returned function is called."""
        self._bind_loop()  # where they will be delivered
        return self.transport.want_all()

    def has_readers(self, name: str) -> bool:
        """Whether anyone reads ``name``: a subscriber here, or another process."""
        info = self._topics.get(name)
        return bool(info and info.subscribers) or self.transport.matched(name)

    def _hold(self, name: str, latched: bool) -> None:
        if name not in self._held:
            self._held.add(name)
            self._want(name, latched)

    def _want(self, name: str, latched: bool) -> None:
        self._bind_loop()
        n = self._interest.get(name, 0) + 1
        self._interest[name] = n
        if n == 1:
            self.transport.want(name, latched)

    def _unwant(self, name: str) -> None:
        n = self._interest.get(name, 0) - 1
        if n > 0:
            self._interest[name] = n
        elif self._interest.pop(name, None) is not None:
            self.transport.unwant(name)

    def topics(self) -> dict[str, TopicInfo]:
        return dict(self._topics)

    # ------------------------------------------------------------ services
    def serve(self, name: str, handler: ServiceHandler) -> None:
        """Offer a service. ``handler(request)`` is async and returns the reply."""
        if name in self._services:
            raise ValueError(f"service {name} is already offered")
        self._services[name] = ServiceInfo(name, handler)
        self.transport.offer(name, functools.partial(self.call, name))

    def unserve(self, name: str) -> None:
        if self._services.pop(name, None) is not None:
            self.transport.withdraw(name)

    def has_service(self, name: str) -> bool:
        """Whether a node offers ``name``, in this process or (networked) in another."""
        return name in self._services or self.transport.has_service(name)

    async def call(self, name: str, request: Any, timeout: float | None = DEFAULT_SERVICE_TIMEOUT_S) -> Any:
        """Call a service; errors and time-outs raise :class:`ServiceError` subclasses."""
        info = self._services.get(name)
        if info is None:  # another process's, or nobody's (ServiceUnavailable)
            return await self.transport.call(name, request, timeout)
        info.calls += 1
        try:
            return await self.clock.wait_for(info.handler(request), timeout)
        except asyncio.TimeoutError:
            info.errors += 1
            raise ServiceTimeout(f"service {name} did not answer within {timeout:g} s") from None
        except ServiceError:
            info.errors += 1
            raise
        except Exception as exc:
            info.errors += 1
            raise ServiceError(f"service {name} failed: {exc}") from exc

    def _bind_loop(self) -> None:
        if self._loop is None:
            try:
                self._loop = asyncio.get_running_loop()
                self._loop_thread = threading.get_ident()
            except RuntimeError:
                pass
