"""The toy protocol's monitor room (its plug-in is ``protocols/toy.py``)."""
