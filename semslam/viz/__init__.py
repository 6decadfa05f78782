"""What a person looks at: a Rerun recording of a run (``rerun_log``), rendered views of the
maps for the HTML report (``map_views``) and the class colours both use (``palette``).

Nothing here is needed to run SLAM; Rerun is imported only when a recording is asked for.
"""
