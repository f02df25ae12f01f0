"""A user's own frames or descriptors end to end, outside the DVC chain: what ``cmal-lcd match``
and ``cmal-lcd loops`` run (the commands only parse arguments and print).

- :mod:`~cmal_lcd.workflows.match_folders`: a reference and a query sequence matched and, with
  ground truth, scored and drawn (:func:`~cmal_lcd.workflows.match_folders.match_folders`);
- :mod:`~cmal_lcd.workflows.loops_folder`: loop closures within one traversal
  (:func:`~cmal_lcd.workflows.loops_folder.loops_folder`);
- :mod:`~cmal_lcd.workflows.folder_features`: the features of such frames, by the extractor
  and the choice the ``extract_features`` stage made.

They write a command's output folder and sit above the libraries they join (data, features,
matching, evaluation, reports), which never import them.
"""
