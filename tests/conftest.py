import os
import tempfile

os.environ.setdefault("XDG_CACHE_HOME", os.path.join(tempfile.gettempdir(), "triadcal-xdg-cache"))
os.environ.setdefault("MPLBACKEND", "Agg")
