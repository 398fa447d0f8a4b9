"""The HTML report of ``skincap demo``: figures (:mod:`.plots`) and the page (:mod:`.html`)."""
