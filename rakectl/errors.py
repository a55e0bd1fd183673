"""One exception tree for the whole project.

Each subclass also inherits the matching built-in, so callers that only know
Python's own exceptions still catch them.
"""


class RakeError(Exception):
    """Base of every error raised on purpose by rakectl."""


class ConfigError(RakeError, ValueError):
    """A configuration file or override is invalid; the message names where."""


class KinematicsError(RakeError, ValueError):
    """A pose is outside the workspace or singular."""


class NonFiniteError(RakeError, ArithmeticError):
    """A NaN or infinity reached a place where only finite numbers may be."""


class DriveFault(RakeError):
    """A drive reported a fault or behaved outside its protocol."""


class CommsTimeout(RakeError, TimeoutError):
    """Expected traffic did not arrive in time."""


class FrameError(RakeError, ValueError):
    """A CAN frame, or a field for one, is malformed.

    Wrong data length, a value outside its wire type (an int16 beyond ±32767 …),
    or a bit pattern the protocol does not define. The message names the frame
    and the field.
    """


class TraceError(RakeError, ValueError):
    """A bus trace or its inputs file is missing, garbled or another run's; the message
    names the file and the line."""


class ApiError(RakeError):
    """The command API failed: the socket cannot be set up, or a reply is unusable."""


class DaemonUnreachable(ApiError, ConnectionError):
    """No daemon answers on the command socket (missing, refused, closed or silent)."""


class CommandRejected(ApiError):
    """The daemon answered a request with an error; the message is the daemon's sentence.

    A command handler raises it (or any other RakeError) to refuse a request.
    """
