"""The paper's stages: matching, cycles and track sampling, two-view geometry, focal start,
incremental and global SfM with bundle adjustment, refinement on all matches and on the images,
and the checks of the user's data (frames, masks, known intrinsics) they rely on."""
