"""Presentation: pictures of values (:mod:`.render`) and the HTML report (:mod:`.report`)."""
