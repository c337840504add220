"""Interactive and animated views: notebook widgets, the lesson, the GIFs of BTs in motion."""
