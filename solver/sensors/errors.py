"""The located error of the sensor-metadata readers: which file, which element."""

from __future__ import annotations

from solver.errors import JobError, Problem


class MetadataError(JobError):
    """A sensor metadata file that cannot be used: ``file`` as the user gave it, ``element`` the
    XML path (``isd/EPH/EPHEMLISTList``) or keyword at fault ("" for the file as a whole).
    Code ``bad_sensor_metadata``; the CLI prints ``file, element E: message`` and exits 2."""

    def __init__(self, file: str, element: str, message: str):
        self.file, self.element, self.reason = file, element, message
        where = f"{file}, element {element}" if element else file
        super().__init__(Problem("bad_sensor_metadata", f"{where}: {message}", (file, element),
                                 {"file": file, "element": element}))
