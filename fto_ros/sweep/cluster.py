"""Reaching a Dask scheduler (sweep/engine.py's cluster path): every way it can fail ends in
one :class:`EngineError` line within the connect timeout.

- :func:`split_address`: ``tcp|tls|ws|wss://HOST:PORT`` only (an in-process or unknown scheme
  made distributed's half-built Client print a traceback 60 s after the error line);
- :func:`reach`: the name looked up and a TCP connection opened, both within the timeout
  (a refused port answers at once instead of after distributed's retries);
- :func:`client`: distributed's handshake first (a port that accepts and says nothing made
  the Client wait for ever), then the Client, in a helper thread given up on after the
  timeout;
- :func:`quiet_dask`: distributed's log lines (reconnection attempts, tracebacks from its
  event loop) are dropped (``FTO_DEBUG=1`` keeps them): the engine says what happened.
"""
from __future__ import annotations

import asyncio
import logging
import os
import socket

from ..core.command_line import one_line
from ..core.errors import EngineError

#: the address schemes of a Dask scheduler reached over the network
SCHEMES = ("tcp", "tls", "ws", "wss")
#: loggers of distributed and the libraries under it, whose lines the engine replaces
_DASK_LOGGERS = ("distributed", "tornado", "asyncio")


def split_address(address: str) -> tuple[str, str, int]:
    """``(scheme, host, port)`` of a scheduler address ``scheme://host:port``; EngineError for
    anything else (an in-process or unknown scheme, no host, a port out of range)."""
    from urllib.parse import urlsplit
    try:
        parts = urlsplit(address)
        port = parts.port
    except ValueError as err:
        raise EngineError(f"bad Dask scheduler address {address!r}: {one_line(err)}") from None
    if parts.scheme not in SCHEMES:
        raise EngineError(f"bad Dask scheduler address {address!r}: the scheme must be one of "
                          f"{', '.join(SCHEMES)}")
    if not parts.hostname or port is None or not 0 < port < 65536 or parts.path not in ("", "/"):
        raise EngineError(f"bad Dask scheduler address {address!r}: expected "
                          f"{parts.scheme}://HOST:PORT")
    return parts.scheme, parts.hostname, port


def quiet_dask() -> None:
    """distributed's log lines (and tornado's, asyncio's, which carry its tracebacks) are
    dropped for the rest of the process, unless FTO_DEBUG is set."""
    if os.environ.get("FTO_DEBUG"):
        return
    import distributed  # noqa: F401  (its import configures its loggers: after that)
    names = [n for n in list(logging.root.manager.loggerDict)
             if any(n == p or n.startswith(p + ".") for p in _DASK_LOGGERS)]
    for name in {*_DASK_LOGGERS, *names}:
        log = logging.getLogger(name)
        log.handlers = [logging.NullHandler()]
        log.propagate = False


def reach(address: str, timeout: float) -> None:
    """Look the scheduler's name up and open (and close) a TCP connection to it, both
    within ``timeout`` s (a resolver that does not answer would block for longer, a refused
    port answers at once); EngineError in one line otherwise."""
    import threading
    import time
    _scheme, host, port = split_address(address)
    box: dict = {}

    def resolve() -> None:
        try:
            box["addresses"] = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        except OSError as err:
            box["error"] = err.strerror or one_line(err)
    t0 = time.monotonic()
    helper = threading.Thread(target=resolve, name="fto-dask-resolve", daemon=True)
    helper.start()
    helper.join(timeout)
    why = box.get("error") or (None if "addresses" in box else f"no answer for the name {host}")
    if why is None:
        family, kind, proto, _, where = box["addresses"][0]
        try:
            with socket.socket(family, kind, proto) as sock:
                sock.settimeout(max(timeout - (time.monotonic() - t0), 0.1))
                sock.connect(where)
        except OSError as err:
            why = "timed out" if isinstance(err, TimeoutError) else (err.strerror or one_line(err))
    if why is not None:
        raise EngineError(f"cannot connect to the Dask scheduler at {address}: {why} "
                          f"(connect timeout {timeout:g} s)")


def _handshake(address: str, timeout: float) -> None:
    """distributed's own connection handshake with ``address``, bounded by ``timeout``: a
    port that accepts and says nothing (no scheduler there) fails here, where the Client
    would wait for ever."""
    from distributed.comm import connect
    from distributed.security import Security

    async def probe():
        comm = await connect(address, timeout=timeout,
                             **Security().get_connection_args("client"))
        await comm.close()
    asyncio.run(asyncio.wait_for(probe(), timeout))


def client(address: str, timeout: float):
    """A distributed Client connected to ``address``, or EngineError (one line) within about
    ``timeout`` s: the handshake first, then the Client, made in a helper thread that is
    given up on (and left to the interpreter's exit) if it does not finish in time."""
    import threading
    try:
        _handshake(address, timeout)
    except (Exception, asyncio.CancelledError) as err:  # noqa: BLE001
        why = "no answer" if isinstance(err, (TimeoutError, asyncio.TimeoutError)) \
            else one_line(err) or type(err).__name__
        raise EngineError(f"no Dask scheduler answers at {address}: {why} (connect timeout "
                          f"{timeout:g} s)") from None
    from distributed import Client
    box: dict = {}

    def make() -> None:
        try:
            box["client"] = Client(address, timeout=timeout, set_as_default=False)
        except BaseException as err:  # noqa: BLE001  reported by the caller
            box["error"] = err
    helper = threading.Thread(target=make, name="fto-dask-connect", daemon=True)
    helper.start()
    helper.join(2 * timeout + 5)
    if "client" in box:
        return box["client"]
    why = one_line(box["error"]) or type(box["error"]).__name__ if "error" in box else \
        f"no answer within {2 * timeout + 5:g} s"
    raise EngineError(f"cannot connect to the Dask scheduler at {address}: {why}")
