"""topos's drop-in for ``topomodelx.utils``."""
