"""One error hierarchy for bagport.

Every error says what failed, where (file, topic, timestamp, field) and how to
fix it.  Constructors take structured fields and build the message, so callers
cannot forget the location.  ``TransientError`` is the only branch a task
retries; everything else fails fast.
"""

from __future__ import annotations

import os

__all__ = [
    "AlignmentError",
    "BagReadError",
    "BagportError",
    "ContractError",
    "DatasetWriteError",
    "DecodeError",
    "EncoderSettingsError",
    "FrameShapeError",
    "ManifestError",
    "OutputInBagError",
    "OutputTakenError",
    "PushError",
    "QualityError",
    "TransientError",
    "ValidationError",
    "VideoError",
]


def _where(**fields: object) -> str:
    parts = [f"{name}={value}" for name, value in fields.items() if value is not None]
    return f" [{', '.join(parts)}]" if parts else ""


def _rebuild(cls: type[BagportError], message: str, state: dict[str, object]) -> BagportError:
    error = cls.__new__(cls)
    Exception.__init__(error, message)
    error.__dict__.update(state)
    return error


class BagportError(Exception):
    """Root of every error bagport raises on purpose."""

    def __reduce__(self) -> tuple[object, tuple[object, ...]]:
        # Keyword-only constructors do not survive the default pickling, and errors
        # cross process boundaries (process pools, Dask workers): rebuild from the message.
        return (_rebuild, (type(self), str(self), dict(self.__dict__)))


class TransientError(BagportError):
    """An I/O failure that may succeed when tried again (network, throttling)."""


class ManifestError(BagportError):
    """The manifest of bags is malformed or names bags that cannot be found."""

    def __init__(
        self,
        what: str,
        *,
        file: str | None = None,
        entry: int | None = None,
        fix: str = "",
        row: int | None = None,
        column: str | None = None,
        line: int | None = None,
    ) -> None:
        self.file = file
        self.entry = entry
        self.row = row
        """Line of a CSV manifest (the header is row 1); a CSV entry is named by its row, not ``bags[i]``."""
        self.column = column
        self.line = line
        """1-based line of a YAML manifest the problem is on."""
        where = f"{file}" if file else "manifest"
        if row is not None:
            where += f", row {row}" + (f" (column {column})" if column else "")
        elif entry is not None:
            where += f", bags[{entry}]"
        if line is not None:
            where += f": line {line}"
        super().__init__(f"{where}: {what}" + (f" Fix: {fix}" if fix else ""))


class ContractError(BagportError):
    """The contract YAML is malformed or does not fit the bags."""

    def __init__(
        self,
        what: str,
        *,
        file: str | None = None,
        line: int | None = None,
        field: str | None = None,
        fix: str = "",
    ) -> None:
        self.file = file
        self.line = line
        self.field = field
        where = file or "contract"
        if line is not None:
            where += f":{line}"
        if field:
            where += f" ({field})"
        super().__init__(f"{where}: {what}" + (f" Fix: {fix}" if fix else ""))


class BagReadError(BagportError):
    """A bag cannot be opened or read."""

    def __init__(self, what: str, *, uri: str, topic: str | None = None, fix: str = "") -> None:
        self.uri = uri
        self.topic = topic
        self.fix = fix
        super().__init__(f"{uri}: {what}{_where(topic=topic)}" + (f" Fix: {fix}" if fix else ""))


class DecodeError(BagportError):
    """A message cannot be turned into a feature value."""

    def __init__(
        self,
        what: str,
        *,
        uri: str | None = None,
        topic: str | None = None,
        t_ns: int | None = None,
        fix: str = "",
    ) -> None:
        self.what = what
        self.uri = uri
        self.topic = topic
        self.t_ns = t_ns
        self.fix = fix
        prefix = f"{uri}: " if uri else ""
        super().__init__(f"{prefix}{what}{_where(topic=topic, t_ns=t_ns)}" + (f" Fix: {fix}" if fix else ""))

    def located(self, *, uri: str, topic: str, t_ns: int) -> DecodeError:
        """The same error with the bag, topic and message time filled in."""
        return DecodeError(
            self.what, uri=self.uri or uri, topic=self.topic or topic, t_ns=self.t_ns or t_ns, fix=self.fix
        )

    def at_entry(self, entry: str) -> DecodeError:
        """The same error naming the contract entry (``contract.yaml:12, observations[key=...]``) it met."""
        return DecodeError(
            f"{self.what} ({entry})", uri=self.uri, topic=self.topic, t_ns=self.t_ns, fix=self.fix
        )


class AlignmentError(BagportError):
    """Streams cannot be put on the frame grid (no overlap, missing data)."""

    def __init__(self, what: str, *, uri: str | None = None, topic: str | None = None, fix: str = "") -> None:
        self.uri = uri
        self.topic = topic
        prefix = f"{uri}: " if uri else ""
        super().__init__(f"{prefix}{what}{_where(topic=topic)}" + (f" Fix: {fix}" if fix else ""))


class VideoError(BagportError):
    """Encoding, remuxing or decoding a video failed."""


class FrameShapeError(VideoError):
    """A frame a clip cannot take as it is: odd sides for 4:2:0 video, or another size than the clip's."""

    def __init__(self, what: str, *, path: str, fix: str) -> None:
        self.what = what
        self.path = path
        self.fix = fix
        super().__init__(f"{path}: {what}. Fix: {fix}")


class EncoderSettingsError(VideoError):
    """The encoder refused its settings (the codec, an option, the pixel format) when it opened."""

    def __init__(self, message: str, *, codec: str, detail: str) -> None:
        self.codec = codec
        self.detail = detail
        """What FFmpeg or PyAV said, without the clip's path."""
        super().__init__(message)


class DatasetWriteError(BagportError):
    """Writing the LeRobot dataset failed; the output folder was left untouched."""


class OutputTakenError(DatasetWriteError):
    """A first write (no ``--overwrite``) found, at its commit, an output another run published while it wrote:
    that output is kept, this run's is not published."""

    def __init__(self, output: str) -> None:
        self.output = output
        super().__init__(
            f"{output} was created by another run while this one was writing it (two runs with one output); "
            "that run's output is kept and this run's was not published there. Fix: write to a new --output, "
            "or, for a LeRobot dataset, add this run's bags to it with --append (the episodes this run staged "
            "are reused); one run at a time per output."
        )


class OutputInBagError(DatasetWriteError):
    """An ``--output`` (or ``--staging``: :attr:`option`) that is, or is inside, one of the run's bags: the
    run would write into a recording, so it refuses before anything is written."""

    def __init__(self, *, option: str, path: str, bag_uri: str) -> None:
        self.option = option
        """The option that names the place: ``--output`` or ``--staging``."""
        self.path = path
        self.bag_uri = bag_uri
        written = "the staged episodes" if option == "--staging" else "the dataset"
        super().__init__(
            f"{option} {path} is inside the bag {bag_uri}: {written} would be written into a recording of the "
            f"run; nothing was written. Fix: choose a {option} outside the bags' folders."
        )


class QualityError(BagportError):
    """Episodes failed QA (or conversion) and the QA policy says the run fails (exit code 1).

    The error crosses the Prefect flow as a failed state's data, so the CLI tells this outcome from bad
    input (exit code 2) by its type; :attr:`MARKER` is only the wording its messages share.
    """

    MARKER = "failed QA or conversion"


class ValidationError(BagportError):
    """A written dataset violates a LeRobot v3.0 invariant or does not load: the file (or folder) concerned,
    what is wrong and the fix."""

    def __init__(self, what: str, *, path: str | os.PathLike[str] | None, fix: str) -> None:
        self.what = what
        self.path = os.fspath(path) if path is not None else None
        """The file or folder the finding is about (``None``: the installation, not the dataset)."""
        self.fix = fix
        prefix = f"{self.path}: " if self.path is not None else ""
        stop = "" if what.endswith(".") else "."
        super().__init__(f"{prefix}{what}{stop} Fix: {fix}")


class PushError(BagportError):
    """Publishing a dataset on the Hugging Face Hub failed or was refused."""
