"""The float EPSSN in PyTorch, built from the model spec JSON (weights/epssn-*.json).

The network mirrors the f64 reference (`epssn_reference::floatref`) layer by layer; the
warp tables are computed with the same geometry the build-time tables use (`epssn-spec`'s
grids and geometry), so the two float networks agree to well below 0.1 mm.
"""

__version__ = "0.1.0"
