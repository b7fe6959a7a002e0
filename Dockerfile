# The service image: runtime dependencies only (no torch, no anny).
FROM python:3.11-slim
WORKDIR /srv
ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1
COPY pyproject.toml README.md ./
COPY app ./app
COPY training ./training
COPY models ./models
RUN pip install --no-cache-dir .
USER nobody
EXPOSE 8000
HEALTHCHECK CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz')"
CMD ["spectral-unions", "serve", "--host", "0.0.0.0", "--port", "8000"]
