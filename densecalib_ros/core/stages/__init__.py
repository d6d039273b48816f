"""The stages a calibration runs, one module each, in the order core.pipeline runs them:

    inputs      the frame sets checked, the configuration resolved for the cameras, the regions
                no match may use (RigImages)
    matching    every frame set matched; the keypoint matches as tracks (Matched)
    runs        one sampling + SfM run on the matches (calibrate_once, sfm_run); a calibration
                from correspondences already made (calibrate_from_tracks)
    refinement  the kept run refined on dense correspondences in the images (RefinedRuns)
    attempt     one matcher's matches calibrated: consensus runs, focal hops, the image
                refinement (calibrate_matched -> Attempt)
    record      the quality record and the warnings, each made once from the finished rig

The policies around a stage (consensus runs, a second matcher) are in core.robust and take the
stage as a callable.
"""
