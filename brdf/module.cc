// Module placeholder; replaced as the module gains sources.
