"""``servowatch import``: a user's own recordings (TDMS, MDF 3/4, Parquet, CSV) through a channel
map into ordinary servowatch logs (docs/import.md). ``mapping`` (the TOML map, pint units),
``source`` (the readers' common form, the format check), one module per reader (``tabular``:
pyarrow, ``tdms``: nptdms, ``mdf``: asammdf), ``timebase`` (intake rules, several rates onto
one grid), ``merge`` (several time bases in bounded memory), ``convert`` (the import)."""

from service.importer.convert import IMPORT_RECORD, ImportResult, import_file, read_import_record
from service.importer.errors import InputError
from service.importer.mapping import ChannelMap, load_map

__all__ = [
    "ChannelMap",
    "IMPORT_RECORD",
    "ImportResult",
    "InputError",
    "import_file",
    "load_map",
    "read_import_record",
]
