"""pcuvd — pulse-coded ultrafast vector Doppler (PC-UVD) and conventional UVD, from channel data
to velocity vectors, numpy in and numpy out over the Rust library.

Quick start::

    import pcuvd
    recording = pcuvd.read_recording("PWI_disk.mat")     # any format `pcuvd process` reads
    result = pcuvd.process(recording)                    # the CLI's chain and defaults
    result.color_doppler                                 # (nz, nx) m/s, > 0 moving away
    result.save("disk-out")                              # what `pcuvd process` writes

Units are SI (m, s, Hz, m/s), each in its keyword's name. Stage functions (`rf_to_iq`,
`beamform`, `svd_filter`, `power_doppler`, `kasai`, `vector_ls`, `vector_irls`,
`decode_hadamard`, `dynamics`, `resistivity_index`) run one step of the chain on arrays; `simulate` makes
recordings with ground truth; `pcuvd.study` runs the paper's studies; `pcuvd.dask.process` runs
one long recording's segments on a Dask cluster (import `pcuvd.dask`, with `distributed` installed).
"""

from . import study
from ._pcuvd import __version__
from ._process import DynamicsError, ProcessResult, dynamics, process, process_option_names
from ._recording import Recording, read_recording
from ._simulate import Truth, simulate, simulate_option_names
from ._stages import (
    beamform,
    decode_hadamard,
    kasai,
    power_doppler,
    resistivity_index,
    rf_to_iq,
    ri_maps,
    svd_filter,
    vector_irls,
    vector_ls,
)

__all__ = [
    "DynamicsError",
    "ProcessResult",
    "Recording",
    "Truth",
    "__version__",
    "beamform",
    "decode_hadamard",
    "dynamics",
    "kasai",
    "power_doppler",
    "process",
    "process_option_names",
    "read_recording",
    "resistivity_index",
    "ri_maps",
    "rf_to_iq",
    "simulate",
    "simulate_option_names",
    "study",
    "svd_filter",
    "vector_irls",
    "vector_ls",
]
