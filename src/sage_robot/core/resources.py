"""Resources: objects the nodes of one process share that are not messages (the simulated
world, the pty of the simulated MCU, the running knowledge base, the launcher).

Each is reached through a :class:`ResourceKey` declared once, next to the code that owns
the object, with the object's type::

    WORLD_RESOURCE: ResourceKey[World] = ResourceKey("sim_world", World)

    ctx.resources.set(WORLD_RESOURCE, world)      # a World, or a type-check error
    world = ctx.resources.get(WORLD_RESOURCE)     # World | None
    world = ctx.resources.require(WORLD_RESOURCE) # World, or MissingResource naming the key

``ctx.resources[KEY]`` and ``ctx.resources[KEY] = value`` read and write the same way.
Keys are the only way in: a bare string is refused.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any, Generic, TypeVar, overload

T = TypeVar("T")
D = TypeVar("D")


class MissingResource(LookupError):
    """A resource that must be there is not (its owner is not running, or not yet)."""


class ResourceKey(Generic[T]):
    """The name of a shared object and its type. ``kind``, where given, is checked when the
    object is put in (leave it out for a protocol or a parametrized type)."""

    __slots__ = ("doc", "kind", "name")

    def __init__(self, name: str, kind: type[T] | None = None, doc: str = "") -> None:
        self.name, self.kind, self.doc = name, kind, doc

    def __repr__(self) -> str:
        return f"ResourceKey({self.name!r})"


def _name(key: object) -> str:
    if not isinstance(key, ResourceKey):
        raise TypeError(f"resources are reached through a ResourceKey, not {key!r}")
    return key.name


class Resources:
    """The shared objects of one process (``NodeContext.resources``), by typed key."""

    def __init__(self, items: Mapping[ResourceKey[Any], Any] | None = None) -> None:
        self._items: dict[str, Any] = {}
        for key, value in (items or {}).items():
            self.set(key, value)

    @overload
    def get(self, key: ResourceKey[T]) -> T | None: ...
    @overload
    def get(self, key: ResourceKey[T], default: D) -> T | D: ...
    def get(self, key: ResourceKey[Any], default: Any = None) -> Any:
        return self._items.get(_name(key), default)

    def require(self, key: ResourceKey[T]) -> T:
        """The resource; :class:`MissingResource` naming the key when it is not there."""
        name = _name(key)
        if name not in self._items:
            why = f" ({key.doc})" if key.doc else ""
            raise MissingResource(f"no resource {name!r}{why}: the node that provides it is not running")
        value: T = self._items[name]
        return value

    def set(self, key: ResourceKey[T], value: T) -> None:
        name = _name(key)
        if key.kind is not None and not isinstance(value, key.kind):
            raise TypeError(f"resource {name!r} is a {key.kind.__name__}, not a {type(value).__name__}")
        self._items[name] = value

    def setdefault(self, key: ResourceKey[T], default: T) -> T:
        """The resource, after putting ``default`` in when it was not there."""
        if _name(key) not in self._items:
            self.set(key, default)
        value: T = self._items[key.name]
        return value

    @overload
    def pop(self, key: ResourceKey[T]) -> T | None: ...
    @overload
    def pop(self, key: ResourceKey[T], default: D) -> T | D: ...
    def pop(self, key: ResourceKey[Any], default: Any = None) -> Any:
        return self._items.pop(_name(key), default)

    def __getitem__(self, key: ResourceKey[T]) -> T:
        return self.require(key)

    def __setitem__(self, key: ResourceKey[T], value: T) -> None:
        self.set(key, value)

    def __delitem__(self, key: ResourceKey[Any]) -> None:
        self._items.pop(_name(key), None)

    def __contains__(self, key: object) -> bool:
        return _name(key) in self._items

    def __iter__(self) -> Iterator[str]:
        """The names of the resources present (for a person reading a report)."""
        return iter(list(self._items))

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        return f"Resources({', '.join(self._items)})"
