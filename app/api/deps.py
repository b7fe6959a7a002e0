"""Dependency aliases shared by the routes."""

from typing import Annotated

from fastapi import Depends, Request

from app.core.config import Settings


def app_settings(request: Request) -> Settings:
    """The settings the app was built with (tests build apps with their own)."""
    return request.app.state.settings


SettingsDep = Annotated[Settings, Depends(app_settings)]
