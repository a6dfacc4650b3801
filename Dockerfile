# arva-emulate for a shared lab: the emulated receiver served over RFC 2217 (the protocol
# of ser2net and labgrid), so a device under test or a test runner on another host opens
# rfc2217://HOST:4000 as if it were a networked serial port. See docs/hil_testing.md.
#
#   docker build -t arva-emulator .
#   docker run --rm -p 127.0.0.1:4000:4000 arva-emulator
#   docker run --rm -p 4000:4000 -v "$PWD/lab:/scenes:ro" arva-emulator \
#       --scene /scenes/lab.toml --port rfc2217-server:0.0.0.0:4000 --serve-any-host
#
# Plain pip install of the package (runtime dependencies only, no extras) and its
# console scripts; nothing is fetched at run time.
FROM python:3.11-slim

WORKDIR /src
COPY pyproject.toml README.md ./
COPY firmware_proto ./firmware_proto
COPY emulator ./emulator
COPY bench ./bench
RUN pip install --no-cache-dir . && rm -rf /src

# Not root: the emulator needs no privilege to listen on an unprivileged port.
RUN useradd --system --no-create-home arva
USER arva
WORKDIR /home

EXPOSE 4000
# Inside the container the server must listen on all of the container's interfaces for
# a published port to reach it, hence 0.0.0.0 and --serve-any-host; publish it on the
# host's loopback (-p 127.0.0.1:4000:4000) unless other lab hosts must reach it.
# arva-emulate handles SIGTERM (docker stop) and exits 0 with its summary on stderr.
ENTRYPOINT ["arva-emulate"]
CMD ["--port", "rfc2217-server:0.0.0.0:4000", "--serve-any-host"]
