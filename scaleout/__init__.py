"""Scale-out of the expensive fits on a Dask cluster (``dask.distributed``).

The fits' own code runs unchanged inside the tasks; this package only decides what a task is,
where its inputs live (shared storage, or scattered once) and how results come back.
"""
