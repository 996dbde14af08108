"""Studies: ``podilqr evaluate``, ``podilqr reproduce``, ``podilqr bench`` and the machine
description they share."""
