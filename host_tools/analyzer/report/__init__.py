"""Stage 6 of the analysis: the report's sections (:mod:`.sections`), the updated model
(:mod:`.model`) and the writers of report.json, report.md, the plots and model.json
(:mod:`.writers`)."""
