-- 0022: meta.pipeline_run's comments say where settings live now (core/settings.py) and what every stage's
-- counts carry: its balance, in = out + rejected, which etl/runs.py checks before a run may end well.
COMMENT ON COLUMN meta.pipeline_run.params IS 'Every setting the stage used (core/settings.py, CITYLOD_* overrides, plus command-line options).';
COMMENT ON COLUMN meta.pipeline_run.counts IS 'Stage counts. Every stage records its balance: in, out, rejected (in = out + rejected, checked: a run that does not add up is failed), unit (what is counted) and out_by_kind (the parts of out, e.g. lod {"drawn": n, "outlines drawn by their parts": n}); then its own figures, e.g. ingest loaded, repaired, rejected_by_reason.';
