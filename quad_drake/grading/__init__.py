"""Grading a student's estimator the way the FCND course meant it (``quad-drake grade``).

``student_template.py`` is the starting file (the course's six functions); ``course.py`` runs a
student's module as a filter for a fleet; ``grader.py`` flies scenarios 06-11 over many seeds
and judges each run on the calibrated criteria of ``criteria.py`` (the grading mode; the
scenarios' own criteria stay the reference's).
"""
