// placeholder while the session builds this file; replaced before landing
