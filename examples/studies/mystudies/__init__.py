"""Study kinds of one's own (a package beside the study files that name them)."""
