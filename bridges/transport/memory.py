"""An in-process bus: the transport API without a network, for fast and exact unit tests.

The analogue of python-can's ``virtual`` interface. Every MemoryBus opened
with the same prefix in one process shares a broker; a published envelope is
handed to every bus of that prefix (the sender's own included, like Zenoh),
which decodes it through the same receive path as the network backends
(version, size, duplicate and reorder checks). Each bus delivers on its own
thread in publication order, as messages would arrive over one link.
"""
from __future__ import annotations

import queue
import threading

from bridges.transport.bus import Bus
from bridges.transport.envelope import DEFAULT_MAX_SIZE

_brokers: dict[str, list["MemoryBus"]] = {}
_brokers_lock = threading.Lock()
_STOP = object()


class MemoryBus(Bus):
    backend = "memory"

    def __init__(self, *, prefix: str, sender: str, max_size: int = DEFAULT_MAX_SIZE):
        super().__init__(prefix=prefix, sender=sender, max_size=max_size)
        self._inbox: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._deliver, name=f"memory-bus-{sender}", daemon=True)
        self._thread.start()
        with _brokers_lock:
            _brokers.setdefault(self.prefix, []).append(self)

    def _send(self, full_key: str, data: bytes) -> None:
        with _brokers_lock:
            peers = list(_brokers.get(self.prefix, ()))
        for bus in peers:
            bus._inbox.put(data)

    def _deliver(self) -> None:
        while True:
            data = self._inbox.get()
            if data is _STOP:
                return
            self._on_envelope(data, source="memory")

    def _close(self) -> None:
        with _brokers_lock:
            buses = _brokers.get(self.prefix, [])
            if self in buses:
                buses.remove(self)
            if not buses:
                _brokers.pop(self.prefix, None)
        self._inbox.put(_STOP)
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=2.0)
