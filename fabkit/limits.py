"""Limits on what fabkit reads: sizes, counts, nesting depth and magnitudes.

Every file reader checks its input against these before it allocates or computes, and
refuses an input beyond one with a one-line error naming the file and the limit
(``docs/troubleshooting.md`` lists them all, section "Limits"). They are far above what
fabkit itself writes, and low enough that no input can take more than a few GB of memory
or a minute of work before it is refused.
"""

from __future__ import annotations

MIB = 1 << 20
GIB = 1 << 30

TEXT_BYTES = 1 * MIB
"""Largest TOML file: spec, process, machine profile, baromorph, swimmer, director."""
JSON_BYTES = 64 * MIB
"""Largest JSON file: toolpath.json, GeoJSON geometry."""
EMBEDDED_TEXT_CHARS = 4 * MIB
"""Longest text array in an .npz: the spec in design.npz, the metadata in toolpath.npz."""
NESTING_DEPTH = 32
"""Deepest nesting of tables, arrays and dotted keys in TOML and JSON (fabkit uses 5)."""

ARCHIVE_BYTES = 1 * GIB
"""Most bytes the arrays of one .npz (or one .npy) take in memory, as its headers declare."""
ARCHIVE_MEMBERS = 64
"""Most arrays in one .npz."""
COMPRESSION_RATIO = 500
"""Highest compression ratio of an .npz member larger than RATIO_FLOOR (deflate's own limit
is about 1030:1; a bomb sits near it, fabkit's own files stay below 450:1)."""
RATIO_FLOOR = 16 * MIB
"""Members up to this size (uncompressed) may have any compression ratio."""

DESIGN_NODES = 2048 * 2048
"""Most nodes of a design's material grid (nu * nv)."""
DESIGN_SURFACES = 64
"""Most surfaces of a design (flat sheet + targets)."""
DESIGN_FEATURES = 32
"""Most features (eps components) and stimulus components of a design."""
MAGNITUDE = 1e6
"""Largest absolute coordinate, length, height, director component or eps a design,
toolpath (mm), height map or mesh may hold; beyond it the numbers are not a sheet."""

TOOLPATH_MOVES = 200_000
"""Most moves (print lines and travels) of a toolpath file."""
TOOLPATH_VERTICES = 20_000_000
"""Most vertices of a toolpath file."""
TOOLPATH_LAYERS = 10_000
"""Most layers of a toolpath file."""

CSV_BYTES = 64 * MIB
"""Largest CSV height map."""
MESH_BYTES = 128 * MIB
"""Largest mesh file (STL, OBJ, PLY)."""
MESH_FACES = 2_000_000
"""Most triangles of a mesh."""
SCAN_BYTES = 256 * MIB
"""Largest scan file (``fabkit compare``): about 20 million points in binary PLY."""
RASTER_HITS = 40_000_000
"""Most (triangle, grid node) pairs tested when resampling a mesh on its grid (about 3 GB
of work arrays); a height-field mesh of 2048 x 2048 nodes needs about 34 million."""

TEMPLATE_CHARS = 16_384
"""Longest G-code template of a machine profile (start_gcode, ...), rendered."""
TEMPLATE_LINE_CHARS = 256
"""Longest line of a rendered G-code template."""

SWIMMER_SHAPES = 1000
"""Most equilibrium shapes along a swimmer's stimulus cycle (stations x legs)."""
SWIMMER_MESH_RINGS = 100
"""Most rings of the swimmer's elastic disc mesh (about 6 rings^2 triangles)."""
WORK_BYTES = 2 * GIB
"""Most memory the largest array of one computation may take, estimated from the input
before it is allocated (the swimmer's dense Stokeslet matrix: 112 N^2 bytes for N points)."""
