"""The process that runs one Python component for the runtime: `python -m kairos_sdk.worker`.

The runtime starts it with one end of a Unix socket pair as its standard input and drives it over the
worker protocol (docs/python.md): the runtime sends commands (birth, core, death, a property change, an
action), the component's calls become requests the runtime answers (read, write, now, sleep, ...), and
each command ends with the component's outcome. Reads and writes go through the runtime's buffers, so the
reader policies stay the runtime's and exact; large image pixels stay in shared memory that both map.
"""

import importlib.util
import json
import mmap
import os
import socket
import struct
import sys
import traceback
import weakref

from . import wire
from .component import (
    ComponentFailed, ContextBase, EndOfStream, Interrupted, Stopped, image_geometry, numpy,
)
from .types import IMAGE, PIXEL_FORMATS, Sample

#: Pixels from this many bytes on go through shared memory (the runtime's `SHARED_FROM_BYTES`).
SHARED_FROM_BYTES = 256 * 1024
#: Bytes before the pixels in a shared buffer, and its magic (`kairos_shm`).
BUFFER_HEADER_LEN = 64
BUFFER_MAGIC = int.from_bytes(b"KPIXBUF1", "little")
#: Mapped buffers kept before the cache starts over (the runtime recycles a few buffers).
MAPPINGS_KEPT = 64

SDK_FOLDER = os.path.dirname(os.path.abspath(__file__))


class Connection:
    """Frames over the socket: writes are gathered and sent when a reply is awaited or a command ends."""

    def __init__(self, sock):
        self.sock = sock
        self.incoming = sock.makefile("rb", buffering=1 << 16)
        self.out = bytearray()

    def send(self, kind, body=b""):
        self.out += wire.HEADER.pack(len(body) + 1, ord(kind))
        self.out += body

    def flush(self):
        if self.out:
            self.sock.sendall(self.out)
            self.out.clear()

    def recv(self):
        head = self.incoming.read(wire.HEADER.size)
        if len(head) < wire.HEADER.size:
            raise EOFError("the runtime closed the worker's connection")
        length, kind = wire.HEADER.unpack(head)
        body = self.incoming.read(length - 1)
        if len(body) < length - 1:
            raise EOFError("the runtime closed the worker's connection")
        return chr(kind), body


class WorkerContext(ContextBase):
    """The `ctx` a component running under the runtime is given."""

    def __init__(self, connection, hello, descriptor):
        super().__init__(hello["id"], descriptor, hello["properties"])
        self._conn = connection
        self._runtime_pid = hello["pid"]
        self._connected = {p["name"]: p["connected"] for p in hello["inputs"]}
        self._mappings = {}
        self._releases = []
        self._held = {}  # data address of a held input image -> (handle, row stride)
        self._allocated = {}  # data address of an image from new_image -> (handle, length)

    # ----- requests -----

    def _request(self, kind, body=b""):
        if self._releases:
            handles = self._releases
            self._releases = []
            self._conn.send("l", wire.U32.pack(len(handles)) + struct.pack(f"<{len(handles)}Q", *handles))
        self._conn.send(kind, body)
        self._conn.flush()
        reply, body = self._conn.recv()
        if reply == "x":
            raise Stopped()
        if reply == "i":
            raise Interrupted()
        if reply == "e":
            raise EndOfStream()
        if reply == "f":
            raise ComponentFailed(body.decode(errors="replace"))
        return reply, body

    def _release_later(self, handle, address):
        # A newer array may sit at the same address (the runtime recycled the buffer): leave it.
        if self._held.get(address, (None,))[0] == handle:
            del self._held[address]
        self._releases.append(handle)

    # ----- inputs -----

    def is_connected(self, input_name):
        self.input_index(input_name)
        return self._connected.get(input_name, False)

    def read(self, input_name):
        """The next sample of `input_name` under its connection's policy, waiting for it."""
        reply, body = self._request("r", struct.pack("<BH", 0, self.input_index(input_name)))
        self._leave_if_nothing(reply)
        return self._sample(wire.Reader(body, 2))

    def try_read(self, input_name):
        """A sample of `input_name` if one is there under its policy, else `None`; never waits."""
        reply, body = self._request("r", struct.pack("<BH", 1, self.input_index(input_name)))
        return None if reply == "n" else self._sample(wire.Reader(body, 2))

    def read_any(self, input_names):
        """(name, sample) from whichever of `input_names` has data first; none starves."""
        indices = [self.input_index(name) for name in input_names]
        reply, body = self._request("y", wire.U16.pack(len(indices)) + struct.pack(f"<{len(indices)}H", *indices))
        self._leave_if_nothing(reply)
        position = wire.U16.unpack_from(body)[0]
        return input_names[position], self._sample(wire.Reader(body, 2))

    def read_synchronized(self, input_names, tolerance):
        """One sample per input, their timestamps within `tolerance` seconds of each other (data fusion)."""
        indices = [self.input_index(name) for name in input_names]
        body = struct.pack("<qH", int(tolerance * 1e9), len(indices)) + struct.pack(f"<{len(indices)}H", *indices)
        kind, reply = self._request("z", body)
        self._leave_if_nothing(kind)
        reader = wire.Reader(reply)
        return [self._sample(reader) for _ in range(reader.one(wire.U16))]

    @staticmethod
    def _leave_if_nothing(reply):
        # In an execution group a read never waits: with nothing there the call ends, and the group calls
        # `core` again when a sample comes.
        if reply == "n":
            raise Interrupted()

    def _sample(self, reader):
        timestamp, time_of_issue, sequence, handle = reader.take(wire.SAMPLE_HEAD)
        if handle:
            # Only an image in shared memory is held for the worker: its array is made when first asked for.
            reader.one(wire.U8)
            width, height, stride, format_index, _ = reader.take(wire.IMAGE_HEAD)
            fd, buffer_id, length = reader.take(wire.SHARED_REF)
            return HeldImageSample(self, handle, (width, height, stride, fd, buffer_id, length),
                                   timestamp, time_of_issue, sequence, wire.FORMATS[format_index])
        data_type, value, extra = wire.decode_payload(reader, self._inline_image)
        sample = Sample(value, timestamp, time_of_issue, sequence, data_type)
        if data_type == IMAGE:
            sample.format = extra
        elif extra is not None:
            sample.intensity = extra
        return sample

    @staticmethod
    def _image_layout(width, height, stride, format_):
        dtype, shape = image_geometry(width, height, format_)
        item = dtype.itemsize
        strides = (stride, item) if len(shape) == 2 else (stride, shape[2] * item, item)
        return dtype, shape, strides

    def _inline_image(self, width, height, stride, format_, where, reader):
        dtype, shape, strides = self._image_layout(width, height, stride, format_)
        return numpy().ndarray(shape, dtype, buffer=bytes(reader.sized()), strides=strides)

    def _held_array(self, handle, geometry, format_):
        """The numpy view of a held image's pixels."""
        width, height, stride, fd, buffer_id, length = geometry
        dtype, shape, strides = self._image_layout(width, height, stride, format_)
        # Read-only: other readers share these pixels; a component that wants to change them copies them.
        array = numpy().ndarray(shape, dtype, buffer=self._map(fd, buffer_id, length), offset=BUFFER_HEADER_LEN,
                                strides=strides)
        address = array.__array_interface__["data"][0]
        self._held[address] = (handle, stride)
        # The runtime holds the sample until this array and every view of it are gone.
        weakref.finalize(array, self._release_later, handle, address)
        return array

    def forward(self, output, sample):
        """Passes `sample` on unchanged but for its time of issue (images: the same pixels, no copy)."""
        if isinstance(sample, HeldImageSample) and sample.untouched():
            # The pixels were never looked at: name them again without making an array.
            index = self.output_index(output)
            port = self.descriptor.outputs[index]
            if "follows_input" in port or port["data_type"] == IMAGE:
                width, height, stride = sample.geometry[:3]
                body = struct.pack("<HBq", index, 1, sample.timestamp) + wire.U8.pack(wire.TAGS[IMAGE])
                body += wire.IMAGE_HEAD.pack(width, height, stride, wire.FORMATS.index(sample.format),
                                             wire.PIXELS_HELD)
                self._conn.send("w", body + struct.pack("<Q", sample._handle))
                return
        super().forward(output, sample)

    def _map(self, fd, buffer_id, length, writable=False):
        """A buffer of the runtime, mapped: read-only for an input's pixels (other readers share them),
        writable for a buffer the runtime allocated for this worker."""
        key = (buffer_id, writable)
        mapping = self._mappings.get(key)
        if mapping is None:
            if len(self._mappings) >= MAPPINGS_KEPT:
                # Arrays still using a mapping keep it alive; the cache only forgets it.
                self._mappings.clear()
            path = f"/proc/{self._runtime_pid}/fd/{fd}"
            with open(path, "r+b" if writable else "rb") as file:
                access = mmap.ACCESS_WRITE if writable else mmap.ACCESS_READ
                mapping = mmap.mmap(file.fileno(), BUFFER_HEADER_LEN + length, access=access)
            magic, found_id = struct.unpack_from("<QQ", mapping, 0)
            if magic != BUFFER_MAGIC or found_id != buffer_id:
                raise ComponentFailed(f"{path} is not the pixel buffer {buffer_id} the runtime named")
            self._mappings[key] = mapping
        return mapping

    # ----- outputs -----

    def new_image(self, width, height, format="rgb8"):  # noqa: A002 - the keyword users write
        """A writable image of `height` × `width` (× channels) in the runtime's shared memory: written on
        an output, it reaches the readers without a copy. Its pixels start as zeros or an older frame's."""
        np = numpy()
        dtype, shape = image_geometry(width, height, format)
        length = width * height * PIXEL_FORMATS[format] * dtype.itemsize
        if length < SHARED_FROM_BYTES:
            return np.zeros(shape, dtype)
        handle, fd, buffer_id = self._allocate(length)
        if handle == 0:
            return np.zeros(shape, dtype)
        array = np.ndarray(shape, dtype, buffer=self._map(fd, buffer_id, length, writable=True),
                           offset=BUFFER_HEADER_LEN)
        self._allocated[array.__array_interface__["data"][0]] = (handle, length)
        return array

    def _allocate(self, length):
        _, body = self._request("a", struct.pack("<Q", length))
        handle, fd, buffer_id, _ = struct.unpack_from("<QiQQ", body)
        return (handle, fd, buffer_id) if fd >= 0 else (0, -1, 0)

    def write(self, output, data, timestamp=None, format=None, intensity=None):  # noqa: A002
        """Writes `data` on `output`; `timestamp` (ns) when the data originated, else now. Checked against
        the output's type: `WrongType` names the port and the type."""
        index, data_type, value, extra = self.checked(output, data, format, intensity)
        body = bytearray(struct.pack("<HBq", index, timestamp is not None, timestamp or 0))
        pixels = self._image_pixels(value) if data_type == IMAGE else None
        wire.encode_payload(body, data_type, value, extra, pixels)
        self._conn.send("w", body)

    def _image_pixels(self, array):
        """How an image's pixels travel: a buffer from `new_image`, an input's own pixels, or a copy."""
        address = array.__array_interface__["data"][0]
        row = array.shape[1] * array.itemsize * (1 if array.ndim == 2 else array.shape[2])
        packed_rows = array.strides[1:] == ((array.itemsize,) if array.ndim == 2 else
                                            (array.shape[2] * array.itemsize, array.itemsize))
        allocated = self._allocated.get(address)
        if allocated is not None and array.flags.c_contiguous and array.nbytes == allocated[1]:
            del self._allocated[address]
            return wire.PIXELS_SHARED, struct.pack("<QB", allocated[0], 0)
        held = self._held.get(address)
        if held is not None and packed_rows and array.strides[0] == held[1] and array.strides[0] >= row:
            return wire.PIXELS_HELD, struct.pack("<Q", held[0])
        np = numpy()
        length = array.shape[0] * row
        if length >= SHARED_FROM_BYTES:
            handle, fd, buffer_id = self._allocate(length)
            if handle:
                target = np.ndarray(array.shape, array.dtype, offset=BUFFER_HEADER_LEN,
                                    buffer=self._map(fd, buffer_id, length, writable=True))
                np.copyto(target, array)
                return wire.PIXELS_SHARED, struct.pack("<QB", handle, 1)
        pixels = np.ascontiguousarray(array).tobytes()
        return wire.PIXELS_INLINE, wire.U32.pack(len(pixels)) + pixels

    # ----- time and the rest -----

    def now(self):
        """The runtime clock, in nanoseconds."""
        _, body = self._request("t")
        return wire.I64S.unpack(body)[0]

    def sleep(self, seconds):
        """Sleeps `seconds` of real time; a stop, pause or control request ends it early (leaving `core`)."""
        self._request("p", wire.I64S.pack(int(seconds * 1e9)))

    def wait_until(self, timestamp):
        """Sleeps until `timestamp` (ns) on the runtime clock."""
        self._request("u", wire.I64S.pack(int(timestamp)))

    def set_period(self, seconds):
        """The period of a periodic component, in seconds."""
        if not seconds > 0:
            raise ValueError(f"a period is a positive number of seconds, got {seconds!r}")
        self._conn.send("q", wire.I64S.pack(int(seconds * 1e9)))

    def stop_requested(self):
        """Whether the runtime asked the component to stop: long loops in `core` check it."""
        _, body = self._request("h")
        return body[:1] == b"\x01"

    def set_status(self, status):
        """What the component shows in telemetry and the studio: anything JSON can carry."""
        self._conn.send("g", json.dumps(status).encode())


class HeldImageSample(Sample):
    """An input image whose pixels stay in the runtime's shared memory: `data` maps them as a numpy array
    the first time it is read, and the runtime holds them until that array (or, if none was made, this
    sample) is gone."""

    def __init__(self, ctx, handle, geometry, timestamp, time_of_issue, sequence, format_):
        self._ctx = ctx
        self._array = None
        self.geometry = geometry
        super().__init__(None, timestamp, time_of_issue, sequence, IMAGE, format_, None, handle)

    @property
    def data(self):
        if self._array is None and self._ctx is not None:
            self._array = self._ctx._held_array(self._handle, self.geometry, self.format)
        return self._array

    @data.setter
    def data(self, value):
        if value is None:
            return  # the dataclass's __init__
        # A component replacing the pixels it never looked at: the runtime may let them go now.
        if self._array is None and self._ctx is not None:
            self._ctx._release_later(self._handle, None)
        self._array = value
        self._ctx = None

    def untouched(self):
        return self._array is None and self._ctx is not None

    def __del__(self):
        # With an array made, the array's own finalizer releases the pixels.
        if self._array is None and self._ctx is not None:
            self._ctx._release_later(self._handle, None)


def _load(hello):
    """The component's class, imported from its file as its pack would be."""
    path = hello["module"]
    folder = os.path.dirname(path)
    if folder not in sys.path:
        sys.path.insert(0, folder)
    name = f"kairos_pack_{hello['pack']}_{os.path.splitext(os.path.basename(path))[0]}"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    cls = getattr(module, hello["class"], None)
    if cls is None:
        raise LookupError(f"{path} no longer defines class {hello['class']}")
    return cls


IMPORTLIB_FOLDER = os.path.dirname(os.path.abspath(importlib.__file__))


def _is_user_code(filename):
    """Frames of the component's own code: neither this SDK's nor the import machinery's (frozen, or
    the importlib package's own files)."""
    return not (filename.startswith((SDK_FOLDER, IMPORTLIB_FOLDER)) or filename.startswith("<frozen "))


def user_traceback(error):
    """The traceback without the SDK's own frames, and the file and line where the component's code went
    wrong: for code that does not compile that is the syntax error's own place, which no frame holds."""
    frames = traceback.extract_tb(error.__traceback__)
    own = [f for f in frames if _is_user_code(f.filename)] or frames
    lines = ["Traceback (most recent call last):\n", *traceback.format_list(own)]
    lines += traceback.format_exception_only(type(error), error)
    if isinstance(error, SyntaxError) and error.filename and error.lineno:
        place = (error.filename, error.lineno)
    else:
        place = next(((f.filename, f.lineno) for f in reversed(frames) if _is_user_code(f.filename)),
                     (None, None))
    return "".join(lines).rstrip(), place


def _failure(error):
    text, (file, line) = user_traceback(error)
    # The last line is "Type: what"; a syntax error puts its file and source line before it.
    message = traceback.format_exception_only(type(error), error)[-1].strip()
    return json.dumps({"message": message, "traceback": text, "file": file, "line": line}).encode()


def _run(conn, call):
    try:
        call()
    except Stopped:
        conn.send("S")
    except Interrupted:
        conn.send("I")
    except EndOfStream:
        conn.send("O")
    except BaseException as error:  # noqa: BLE001 - any failure of the component's code is reported
        conn.send("E", _failure(error))
    else:
        conn.send("D")
    conn.flush()


def main():
    # The socket arrives as standard input; standard input itself becomes /dev/null so that a component
    # reading it never eats the protocol.
    sock = socket.socket(fileno=os.dup(0))
    devnull = os.open(os.devnull, os.O_RDONLY)
    os.dup2(devnull, 0)
    conn = Connection(sock)
    try:
        kind, body = conn.recv()
    except EOFError:
        return 0
    if kind != "H":
        sys.stderr.write(f"kairos worker: expected the runtime's hello, got {kind!r}\n")
        return 2
    hello = json.loads(body)
    if hello.get("protocol") != wire.PROTOCOL_VERSION:
        conn.send("E", json.dumps({"message": f"the runtime speaks worker protocol {hello.get('protocol')}, "
                                              f"this SDK {wire.PROTOCOL_VERSION}", "traceback": "", "line": None}
                                  ).encode())
        conn.flush()
        return 2
    try:
        cls = _load(hello)
        component = cls()
        ctx = WorkerContext(conn, hello, cls.descriptor)
    except BaseException as error:  # noqa: BLE001 - reported to the runtime with its traceback
        conn.send("E", _failure(error))
        conn.flush()
        return 1
    conn.send("R")
    conn.flush()
    while True:
        try:
            kind, body = conn.recv()
        except EOFError:
            return 0
        if kind == "B":
            _run(conn, lambda: component.birth(ctx))
        elif kind == "C":
            _run(conn, lambda: component.core(ctx))
        elif kind == "X":
            _run(conn, lambda: component.death(ctx))
        elif kind == "P":
            change = json.loads(body)
            ctx.properties[change["name"]] = change["value"]
            _run(conn, lambda: component.property_changed(change["name"], change["value"], ctx))
        elif kind == "A":
            name = json.loads(body)["name"]
            _run(conn, lambda: component.action(name, ctx))
        elif kind == "Q":
            return 0
        else:
            sys.stderr.write(f"kairos worker: unknown command {kind!r}\n")
            return 2


if __name__ == "__main__":
    sys.exit(main())
