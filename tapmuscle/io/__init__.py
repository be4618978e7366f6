"""Files in and out: recordings (``t_s,u_v,l_mm`` CSVs), plant parameter files, command signals.

The lowest layer of :mod:`tapmuscle` above the numerics packages: it reads and writes files and
validates them (errors name the file, line and column), and knows nothing of FMUs or plots.
"""

from tapmuscle.io.identification_file import (IdentificationFileError, IdentifiedModel, read_identification,
                                              write_identification)
from tapmuscle.io.plant_file import PlantFileError, plant_file_text, read_plant_file, write_plant_file
from tapmuscle.io.recording import Recording, RecordingError, atomic_write_text, read_recording, write_recording
from tapmuscle.io.signals import parse_input_spec

__all__ = ["Recording", "RecordingError", "read_recording", "write_recording", "atomic_write_text",
           "PlantFileError", "read_plant_file", "write_plant_file", "plant_file_text", "parse_input_spec", "IdentificationFileError",
           "IdentifiedModel", "read_identification", "write_identification"]
