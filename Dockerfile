# The service image: runtime dependencies only (no torch, no anny), non-root, models baked in.
# Stage 1 builds wheels for the project and its pinned dependencies; stage 2 installs only those.
FROM python:3.11-slim AS build
WORKDIR /src
COPY pyproject.toml README.md ./
COPY app ./app
COPY training ./training
RUN pip wheel --no-cache-dir --wheel-dir /wheels .

FROM python:3.11-slim
ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 \
    SPECTRAL_UNIONS_MODELS_DIR=/srv/models \
    SPECTRAL_UNIONS_DATABASE_PATH=/var/lib/spectral-unions/shapes.sqlite
COPY --from=build /wheels /wheels
RUN pip install --no-cache-dir --no-index /wheels/*.whl && rm -rf /wheels \
    && useradd --system --uid 10001 spectral \
    && mkdir -p /var/lib/spectral-unions && chown spectral /var/lib/spectral-unions
COPY models /srv/models
USER spectral
VOLUME /var/lib/spectral-unions
EXPOSE 8000
HEALTHCHECK --interval=10s --timeout=3s --start-period=20s \
    CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/readyz', timeout=2)"
CMD ["spectral-unions", "serve", "--host", "0.0.0.0", "--port", "8000"]
