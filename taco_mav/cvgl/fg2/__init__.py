"""FG2 (vita-epfl/FG2) behind the Matcher protocol: the adapter (adapter.py), the fast path and its mmcv kernel
(fast.py, mmcv.py), the published model (published.py), the import shim for a checkout (shim.py), a tiny model
the loading code is tested on (tiny.py), and crops cut on the GPU (device_crops.py). torch loads only when an FG2
matcher is built (the `[fg2]` extra)."""
