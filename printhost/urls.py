"""Top-level URL map: pages, admin, login, static files, and the API (the slicers' paths)."""

from __future__ import annotations

from django.contrib import admin
from django.contrib.auth import views as auth_views
from django.contrib.staticfiles.views import serve as serve_static
from django.urls import path, re_path

from printhost import hostfiles, pages
from printhost.api import api
from printhost.logins import ThrottledLoginView
from printhost.metrics_view import metrics

handler403 = "printhost.pages.denied"
handler500 = "printhost.errors.server_error"

urlpatterns = [
    path("admin/", admin.site.urls),
    path("accounts/login/", ThrottledLoginView.as_view(), name="login"),
    path("accounts/logout/", auth_views.LogoutView.as_view(), name="logout"),
    path("", pages.dashboard, name="dashboard"),
    path("printers/<slug:slug>/", pages.printer_page, name="printer"),
    path("jobs/<int:job_id>/", pages.job_page, name="job"),
    path("jobs/<int:job_id>/resume/", pages.resume_page, name="resume"),
    path("account/", pages.account, name="account"),
    path("history/", pages.history, name="history"),
    path("farm/", pages.farm, name="farm"),
    path("metrics", metrics, name="metrics"),
    path("host/files/<int:job_id>", hostfiles.job_file, name="host-file"),
    # printhost runs without a front web server: daphne serves the few static
    # files itself, found by the staticfiles finders (no collectstatic step).
    re_path(r"^static/(?P<path>.+)$", serve_static, {"insecure": True}),
    path("", api.urls),
]
