"""Running a scene to files: the frame loop and summary (runner), USD output, checkpoints, previews."""
