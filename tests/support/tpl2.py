"""A raw TPL2 test client over a real TCP socket: sends exact bytes, reads exact lines.

Deliberately independent of the server's own protocol code, so the tests check the wire.
"""

from __future__ import annotations

import asyncio
import re


class RawClient:
    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter):
        self.reader, self.writer = reader, writer
        self.greeting = ""
        self.lines: list[str] = []  # lines read ahead and not consumed yet

    @classmethod
    async def connect(cls, port: int, *, login: tuple[str, str] | None = ("admin", "admin"),
                      greeting: bool = True) -> "RawClient":
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        client = cls(reader, writer)
        if greeting:
            client.greeting = await client.readline()
        if login:
            await client.send(f'AUTH PLAIN "{login[0]}" "{login[1]}"')
            reply = await client.readline()
            assert reply.startswith("AUTH OK"), reply
        return client

    async def send(self, text: str, end: str = "\n") -> None:
        self.writer.write((text + end).encode("latin-1"))
        await self.writer.drain()

    async def send_bytes(self, data: bytes) -> None:
        self.writer.write(data)
        await self.writer.drain()

    async def readraw(self, timeout: float = 10.0) -> bytes:
        line = await asyncio.wait_for(self.reader.readline(), timeout)
        if not line:
            raise ConnectionError("connection closed")
        return line

    async def readline(self, timeout: float = 10.0) -> str:
        """The next line not yet consumed (lines put aside by :meth:`until` come first)."""
        if self.lines:
            return self.lines.pop(0)
        return await self._read(timeout)

    async def _read(self, timeout: float) -> str:
        raw = await self.readraw(timeout)
        assert raw.endswith(b"\n"), raw
        return raw.decode("ascii").rstrip("\r\n")

    async def until(self, cmd_id: int, timeout: float = 10.0) -> list[str]:
        """Lines of command ``cmd_id`` up to and including its final line; lines of other ids
        read meanwhile are put aside for later calls."""
        final = re.compile(rf"^{cmd_id} COMMAND (COMPLETE|FAILED|ABORTEDBY \d+|TIMEOUT)$")
        out = []
        for line in [x for x in self.lines if x.split(" ", 1)[0] == str(cmd_id)]:
            self.lines.remove(line)
            out.append(line)
            if final.match(line):
                return out
        while True:
            line = await self._read(timeout)
            if line.split(" ", 1)[0] != str(cmd_id):
                self.lines.append(line)
                continue
            out.append(line)
            if final.match(line):
                return out

    async def command(self, cmd_id: int, text: str, timeout: float = 10.0) -> list[str]:
        await self.send(f"{cmd_id} {text}")
        return await self.until(cmd_id, timeout)

    async def get(self, obj: str, cmd_id: int = 99) -> str:
        lines = await self.command(cmd_id, f"GET {obj}")
        assert lines[0] == f"{cmd_id} COMMAND OK", lines
        data = lines[1]
        prefix = f"{cmd_id} DATA INLINE {obj}="
        assert data.startswith(prefix), data
        return data[len(prefix):]

    async def members(self, obj: str = "") -> list[str]:
        """The names of ``obj``'s members, walked as TPL2 clients do: ``!MEMBERS`` is their
        number, ``<i>!NAME`` each name ("" = the root)."""
        prefix = f"{obj}." if obj else ""
        count = int(await self.get(f"{obj}!MEMBERS"))
        return [(await self.get(f"{prefix}<{i}>!NAME")).strip('"') for i in range(count)]

    async def close(self) -> None:
        self.writer.close()
        try:
            await self.writer.wait_closed()
        except (ConnectionError, OSError):
            pass
