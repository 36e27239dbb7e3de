"""Reports: what a results folder shows, as figures, tables and pages.

Modules, by concern:

- :mod:`~eha.reports.thesis`: the thesis reproduction (``eha reproduce``, ``eha report
  thesis``): the chapter-5 campaigns and their report, the chapter-6 identification table.
- :mod:`~eha.reports.plots`: figures and tables of simulations and simulation campaigns
  (``eha simulate --plot``, ``eha plot``).
- :mod:`eha.reports.html`: ``eha report html``, one self-contained interactive page of a
  results folder (read, figures, sections, page; its script and style are package data).

The top of the domain: it reads every layer below (models, identification, explain, health,
prognostics) and the result store; only the command line (:mod:`eha.cli`) is above it. The
package imports nothing itself.
"""
