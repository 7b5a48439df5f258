"""The /ui pages (HTML, JS, CSS), a package only so setuptools ships them as package data."""
