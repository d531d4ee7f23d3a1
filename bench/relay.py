"""A bare websockets relay: every frame one client sends goes, unparsed, to every other client (or, with
--echo, straight back to its sender).

The baseline for bench/roundtrip.py and bench/teleop.py: what the WebSocket layer alone costs on this machine.
"""

from __future__ import annotations

import argparse
import asyncio

from websockets.asyncio.server import ServerConnection, broadcast, serve


async def main(host: str, port: int, echo: bool = False) -> None:
    clients: set[ServerConnection] = set()

    async def relay(ws: ServerConnection) -> None:
        clients.add(ws)
        try:
            async for frame in ws:
                if echo:
                    await ws.send(frame)
                else:
                    broadcast([c for c in clients if c is not ws], frame)
        finally:
            clients.discard(ws)

    async with serve(relay, host, port, compression=None, max_size=None):
        print(f"relay: listening on ws://{host}:{port}", flush=True)
        await asyncio.Future()


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--echo", action="store_true", help="send each frame back to its sender")
    args = parser.parse_args()
    try:
        asyncio.run(main(args.host, args.port, args.echo))
    except KeyboardInterrupt:
        pass
