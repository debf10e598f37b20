"""The application: the ``ase-spin`` command line, its input files, and the
ahead-of-time compilation (``ase-spin compile``)."""
