"""The print farm: jobs that wait for any matching printer, and the dispatcher.

- `models.py`: `FarmJob`, a file waiting for a printer, with its requirements.
- `requirements.py`: what a farm job asks of a printer and whether one meets it
  (pure: no Django, no clock).
- `storing.py`: a farm upload stored once, checked and analysed.
- `matching.py`: which printers a waiting job may go to, and why it waits.
- `dispatch.py`: the dispatcher's pass and its atomic claim.

Kept import-light: `jobs.models` imports the model from here.
"""
