"""Is this pose trustworthy? The quality gate: every check a pose must pass to be published.

A wrong pose published with confidence is the worst outcome, so a pose is accepted only when
- enough keypoints agree with it (inliers, fitness) and they fix all six degrees of freedom;
- its overlap lies on the target's surfaces at the keypoints' resolution, and its feature support
  is more than chance gives in a search of this size (evidence.py: neither depends on how large
  the target is);
- enough of the original feature matches agree with it (geometry alone aligns unrelated planes),
  more when free space cannot be checked from both sides (a map has no viewpoint);
- neither cloud puts surfaces into space the other sensor saw through, and the surface both saw
  was seen from the same side (visibility.py);
- no twin of the pose turned about the scene's symmetry (a corridor's half turn, a box room's
  quarter turn) is one the evidence cannot tell from it (rivals.py: when two poses fit, neither
  can be trusted);
- at least one independent neighbourhood of surface faces every direction: where none does, the
  pose slides along a repeated structure (a bookshelf's bays) and fits as well (slide.py);
- it keeps to the gravity prior, lies inside the search region a hint gave, and
  (acceptance.reverse_check) registering the target to the source gives it back.

Each figure is measured in its own module and gathered by measure.py into figures.py's Figures;
judge.py makes every decision, with every reason. The pipeline measures and judges; the
calibration (regor-calibrate-gate) rebuilds the figures from the benchmark's CSVs and asks the
same judge. Nothing else decides whether a pose is accepted.
"""
