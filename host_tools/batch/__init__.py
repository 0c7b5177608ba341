"""Batch analysis of fleets of recordings on Dask (``ddrobot batch``): run sets from a folder
tree or a manifest (:mod:`.sets`), one subprocess-isolated analyzer task per set written
atomically (:mod:`.task`), the Dask driver (:mod:`.run`), the fleet table and its drift report
(:mod:`.fleet`), the command (:mod:`.cli`) and a generated fleet (:mod:`.fleetgen`)."""
