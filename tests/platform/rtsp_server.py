"""An RTSP server for the tests: GStreamer's (gst-rtsp-server), run by the system's python3
with its GObject bindings (Debian: gir1.2-gst-rtsp-server-1.0, python3-gi,
gstreamer1.0-plugins-ugly for x264). Serves a live test pattern as H.264 at
rtsp://127.0.0.1:<port>/test and prints the port once it listens.

    /usr/bin/python3 tests/platform/rtsp_server.py [WIDTH HEIGHT]
"""

import sys

import gi

gi.require_version("Gst", "1.0")
gi.require_version("GstRtspServer", "1.0")
from gi.repository import GLib, Gst, GstRtspServer  # noqa: E402

Gst.init(None)
server = GstRtspServer.RTSPServer()
server.set_address("127.0.0.1")
server.set_service("0")  # a free port
factory = GstRtspServer.RTSPMediaFactory()
width, height = (int(v) for v in sys.argv[1:3]) if len(sys.argv) > 2 else (320, 240)
factory.set_launch(
    f"( videotestsrc is-live=true pattern=smpte ! video/x-raw,width={width},height={height},"
    "framerate=10/1"
    " ! x264enc tune=zerolatency speed-preset=ultrafast key-int-max=10"
    " ! rtph264pay name=pay0 pt=96 )"
)
factory.set_shared(True)
server.get_mount_points().add_factory("/test", factory)
server.attach(None)
print(server.get_bound_port(), flush=True)
GLib.MainLoop().run()
